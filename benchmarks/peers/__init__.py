"""Peer DQN implementations run under the benchmark protocol (``python -m benchmarks run``).

- :mod:`~benchmarks.peers.tutorial_loop`: the PyTorch DQN tutorial's loop in plain PyTorch.
- :mod:`~benchmarks.peers.sb3_dqn`: Stable-Baselines3 DQN with rl-zoo's CartPole settings
  (the ``bench`` extra).

Both evaluate through :mod:`~benchmarks.peers.protocol`, so their ``summary.json`` reads like
a ``train()`` run's.
"""
