"""Replay-buffer storages and their checkpoints, beside TorchRL's ``LazyTensorStorage``.

- :mod:`~trl_cartpole.storage.chunked`: a ``LazyTensorStorage`` whose checkpoint writes only
  the rows filled since the last one (a buffer of millions of transitions saved in seconds);
- :mod:`~trl_cartpole.storage.frames`: Atari frames stored once, not four times per
  transition (a frame stack rebuilt on sampling);
"""
