"""Peer DQN implementations run under the benchmark protocol (``python -m benchmarks run``).

- :mod:`~benchmarks.peers.tutorial_loop`: the PyTorch DQN tutorial's loop in plain PyTorch.
- :mod:`~benchmarks.peers.sb3_dqn`: Stable-Baselines3 DQN with rl-zoo's CartPole settings
  (the ``bench`` extra).
- :mod:`~benchmarks.peers.sbx_dqn`: SBX (Stable-Baselines3 in JAX) DQN with the same rl-zoo
  settings, from a virtual environment of its own.
- :mod:`~benchmarks.peers.tianshou_dqn`: Tianshou 2 DQN with its own CartPole example's
  settings, from a virtual environment of its own (``benchmarks.harness.peer_python``).

All evaluate through :mod:`~benchmarks.peers.protocol`, so their ``summary.json`` reads like
a ``train()`` run's.
"""
