"""Opt-in rewrites of stock TorchRL parts, all behind one switch: ``fast=true``.

The default run calls TorchRL's own ``DQNLoss`` and ``MultiStepTransform``.
``fast=true`` swaps in, where they apply, these rewrites of the same arithmetic; each module's
docstring gives its measured gain, and each is tested bitwise against the stock part:

- :mod:`~trl_cartpole.fast.loss`: ``DQNLoss.forward`` on plain tensors;
- :mod:`~trl_cartpole.fast.n_step`: ``MultiStepTransform``'s windows on tensors.
"""
