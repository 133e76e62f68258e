"""The factories: each returns a TorchRL object and takes the arguments of the TorchRL class it
builds, with TorchRL's meanings and behaviour.

One module a part: ``env`` (``TransformedEnv(GymWrapper)``), ``models`` (``QValueActor``),
``exploration`` (``EGreedyModule``), ``replay`` (``TensorDictReplayBuffer``), ``losses``
(``DQNLoss``, ``SoftUpdate``/``HardUpdate``), ``optim`` (AdamW and one gradient step) and
``collectors`` (``Collector``). What an env is lives in :mod:`trl_cartpole.envs`, the storages
beside TorchRL's in :mod:`trl_cartpole.storage`. They import nothing of the
application (the config schema, its validation, the run, the command line): the import-linter
contract in ``pyproject.toml`` holds it, and ``trl_cartpole.run.from_config`` joins the two.

One thing happens on import, here and nowhere else: where the torchrl wheel's C++ extension
does not load against the installed torch (torchrl 0.14.1 beside torch 2.13.0's CPU build),
TorchRL's prioritized sampler has no segment trees, and
:func:`~trl_cartpole.compat.install_segment_trees_if_missing` gives it pure-torch ones.
Where the extension loads, nothing of TorchRL is changed.
"""

from trl_cartpole.compat import install_segment_trees_if_missing

install_segment_trees_if_missing()
