"""Opt-in rewrites of stock TorchRL parts, all behind one switch: ``fast=true``.

The default run calls TorchRL's own ``DQNLoss`` and ``MultiStepTransform``.
``fast=true`` swaps in, where they apply, these rewrites of the same arithmetic; each module's
docstring gives its measured gain, and each is tested bitwise against the stock part:

- :mod:`~trl_cartpole.fast.loss`: ``DQNLoss.forward`` on plain tensors;
- :mod:`~trl_cartpole.fast.n_step`: ``MultiStepTransform``'s windows on tensors.

Together, over docs/performance.md's 20 seeds (an Intel Xeon, 2026-12-03): the same frames to
solve on every seed, 0.8x the default's seconds (interquartile means 7.1 and 8.0 s against 9.2
and 10.3 s, the intervals apart, at the two evaluation intervals).
"""
