"""Peer DQN implementations run under this project's benchmark protocol (``scripts/benchmark.py``).

- :mod:`~trl_cartpole.peers.tutorial_loop`: the seeds' PyTorch tutorial loop in plain PyTorch.
- :mod:`~trl_cartpole.peers.sb3_dqn`: Stable-Baselines3 DQN with rl-zoo's CartPole settings
  (the ``bench`` extra).

Both evaluate through :mod:`~trl_cartpole.peers.protocol`, so their ``summary.json`` reads like
a ``train()`` run's.
"""
