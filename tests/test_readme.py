"""The README's reuse example runs as written."""

from __future__ import annotations

import re

from .conftest import ROOT


def test_readme_reuse_example_runs(capsys):
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Reuse the components in another TorchRL project", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.DOTALL).group(1)
    exec(compile(code, "README.md", "exec"), {})
    assert "last TD loss" in capsys.readouterr().out


def test_readme_variant_heads_example_runs():
    from torchrl.modules import DistributionalQValueActor, NoisyLinear, QValueActor
    from torchrl.objectives import DistributionalDQNLoss, DQNLoss

    from trl_cartpole.envs import make_env

    readme = (ROOT / "README.md").read_text()
    section = readme.split("## DQN variants", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.DOTALL).group(1)
    namespace = {"env": make_env("CartPole-v1", seed=0)}
    exec(compile(code, "README.md", "exec"), namespace)
    assert isinstance(namespace["actor"], QValueActor)
    assert any(isinstance(m, NoisyLinear) for m in namespace["actor"].modules())
    assert isinstance(namespace["loss"], DQNLoss) and namespace["loss"].double_dqn
    assert isinstance(namespace["c51"], DistributionalQValueActor)
    assert isinstance(namespace["c51_loss"], DistributionalDQNLoss)
