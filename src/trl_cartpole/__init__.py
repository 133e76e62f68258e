"""trl_cartpole: a modular Deep Q-Learning pipeline built from stock TorchRL parts.

One module per concern (``envs``, ``models``, ``exploration``, ``buffers``, ``losses``,
``collectors``, ``update``, ``evaluation``, ``checkpoint``, ``metrics``, ``plotting``), each
factory returning a TorchRL object; ``train.train(cfg)`` composes them.
"""
