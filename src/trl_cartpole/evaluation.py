"""Greedy evaluation on a separate env: returns, lengths and initial-state values."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import EnvBase, ExplorationType, set_exploration_type

__all__ = ["EvalResult", "evaluate"]


@dataclass
class EvalResult:
    """Per-episode figures of one evaluation."""

    returns: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    initial_values: list[float] = field(default_factory=list)  # max_a Q(s_0, a) per episode

    @property
    def mean(self) -> float:
        return float(torch.tensor(self.returns).mean())

    @property
    def std(self) -> float:
        return float(torch.tensor(self.returns).std(unbiased=False))

    @property
    def initial_value(self) -> float:
        return float(torch.tensor(self.initial_values).mean())


@torch.no_grad()
def evaluate(
    actor: TensorDictModuleBase, env: EnvBase, episodes: int = 20, max_steps: int = 10_000
) -> EvalResult:
    """Play ``episodes`` episodes with the greedy policy (``ExplorationType.DETERMINISTIC``).

    Episodes run one after the other on ``env``, whose seed was set once at creation, so the
    sequence of start states is fixed for a given seed. ``actor`` must write ``action`` and
    ``action_value`` (a ``QValueActor``), so exploration modules are not part of it.
    """
    result = EvalResult()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(episodes):
            rollout = env.rollout(max_steps, actor, break_when_any_done=True)
            result.returns.append(float(rollout["next", "reward"].sum()))
            result.lengths.append(int(rollout.shape[-1]))
            result.initial_values.append(float(rollout[0]["action_value"].max()))
    return result
