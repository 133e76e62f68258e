"""Greedy evaluation on a separate env: returns, lengths and initial-state values."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from omegaconf import OmegaConf
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase, TensorDictSequential
from torchrl.envs import EnvBase, ExplorationType, set_exploration_type
from torchrl.modules import EGreedyModule

from trl_cartpole.checkpoint import load_policy, read_checkpoint_config, read_observation_norm
from trl_cartpole.envs import make_env_from_config
from trl_cartpole.models import expected_action_values, make_q_actor_for_env

__all__ = [
    "EpsilonGreedy",
    "EvalResult",
    "evaluate",
    "evaluate_checkpoint",
    "first_episode_mask",
]


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


def first_episode_mask(done: torch.Tensor) -> torch.Tensor:
    """``[E, T]`` bool: True for the steps of each env's first episode, its last step included.

    ``done`` is ``[E, T]``; a step belongs to the first episode while no earlier step was done.
    """
    done = done.long()
    return (done.cumsum(-1) - done) == 0


class EpsilonGreedy(TensorDictModuleBase):
    """TorchRL's ``EGreedyModule`` with a fixed epsilon, active whatever the exploration type.

    Evaluation runs under ``DETERMINISTIC`` (noisy layers use their mean weights), where
    ``EGreedyModule`` would do nothing; this runs it under ``RANDOM`` on its own.
    """

    def __init__(self, action_spec, epsilon: float) -> None:
        super().__init__()
        self.egreedy = EGreedyModule(action_spec, eps_init=epsilon, eps_end=epsilon)
        self.in_keys, self.out_keys = self.egreedy.in_keys, self.egreedy.out_keys

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        with set_exploration_type(ExplorationType.RANDOM):
            return self.egreedy(tensordict)


@torch.no_grad()
def evaluate(
    actor: TensorDictModuleBase, env: EnvBase, max_steps: int = 10_000, epsilon: float = 0.0
) -> EvalResult:
    """Play one greedy episode (``ExplorationType.DETERMINISTIC``) in each env of ``env``.

    ``env`` is a batched env of batch size ``[E]`` (``make_env(..., num_envs=E)``): the rollout
    runs until every env has finished one episode (or ``max_steps``), and only each env's first
    episode counts. ``actor`` must write ``action_value`` (a ``QValueActor`` or a
    ``DistributionalQValueActor``). With ``epsilon > 0`` each action is replaced by a uniform
    random one with that probability (the Atari protocol's epsilon = 0.05 evaluation).
    """
    policy = actor
    if epsilon > 0:
        policy = TensorDictSequential(actor, EpsilonGreedy(env.action_spec, epsilon))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        rollout = env.rollout(max_steps, policy, break_when_all_done=True)  # [E, T]
    if rollout.ndim == 1:  # a single, unbatched env: [T] -> [1, T]
        rollout = rollout.unsqueeze(0)
    first = first_episode_mask(rollout["next", "done"].squeeze(-1))  # [E, T]
    rewards = rollout["next", "reward"].squeeze(-1)  # [E, T]
    initial_q = expected_action_values(actor, rollout["action_value"][:, 0])  # [E, num_actions]
    return EvalResult(
        returns=(rewards * first).sum(-1).tolist(),
        lengths=first.sum(-1).tolist(),
        initial_values=initial_q.max(-1).values.tolist(),
    )


def evaluate_checkpoint(
    checkpoint: str, episodes: int = 100, seed: int | None = None, epsilon: float = 0.0
) -> tuple[EvalResult, dict]:
    """Rebuild the policy a checkpoint was trained with, load it, and evaluate it greedily.

    The env and network come from the config stored in the checkpoint's manifest; ``seed``
    defaults to the training seed plus twice the eval seed offset (the final evaluation's).
    Returns the result and the stored config as a dict.
    """
    cfg = read_checkpoint_config(checkpoint)
    if seed is None:
        seed = cfg.seed + 2 * cfg.eval.seed_offset
    env = make_env_from_config(
        cfg.env, seed, num_envs=episodes, observation_norm=read_observation_norm(checkpoint)
    )
    actor = make_q_actor_for_env(env, cfg.network)
    load_policy(checkpoint, actor)
    result = evaluate(actor, env, cfg.eval.max_steps, epsilon)
    env.close()
    return result, OmegaConf.to_container(OmegaConf.structured(cfg))
