"""Opt-in rewrites of stock TorchRL parts, all behind one switch: ``fast=true``.

The default run calls TorchRL's own ``DQNLoss``, ``SoftUpdate`` and ``MultiStepTransform``.
``fast=true`` swaps in, where they apply, these rewrites of the same arithmetic; each module's
docstring gives its measured gain, and each is tested bitwise against the stock part:

- :mod:`~trl_cartpole.fast.loss`: ``DQNLoss.forward`` on plain tensors;
- :mod:`~trl_cartpole.fast.soft_update`: ``SoftUpdate.step`` in one fused lerp;
- :mod:`~trl_cartpole.fast.n_step`: ``MultiStepTransform``'s windows on tensors;
- :mod:`~trl_cartpole.fast.compiled_update`: with ``compile=true``, the whole update as one
  function of tensors for ``torch.compile``.
"""
