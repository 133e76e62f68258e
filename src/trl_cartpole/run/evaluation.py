"""Greedy evaluation on a separate env, and the evaluator that keeps the best policy.

:func:`evaluate` plays one greedy episode per env of a batched env. :class:`Evaluator` runs it
every ``eval.interval_frames`` frames with the training clock stopped, keeps the best weights
(saving them as the ``best`` policy checkpoint) and the point where the run was solved: the
greedy mean reaching the solve threshold (Gymnasium's ``reward_threshold``, 475 for
CartPole-v1).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torchrl.envs import (
    DoubleToFloat,
    DTypeCastTransform,
    EnvBase,
    ExplorationType,
    GymWrapper,
    ObservationNorm,
    RewardSum,
    StepCounter,
    TransformedEnv,
    set_exploration_type,
)
from torchrl.envs.transforms import VecGymEnvTransform
from torchrl.modules import DistributionalQValueActor, EGreedyModule, QValueActor

from trl_cartpole.compat import PARTIAL_STEP_KEY, gym_env, next_step_input
from trl_cartpole.envs.faults import StepAlarm, StepDeadline
from trl_cartpole.parts.env import OBSERVATION_KEY
from trl_cartpole.parts.models import expected_action_values
from trl_cartpole.run.progress import Progress, resident_mb

__all__ = [
    "Candidate",
    "EpsilonGreedy",
    "EvalCurve",
    "EvalResult",
    "Evaluation",
    "Evaluator",
    "evaluate",
    "evaluate_on_vector_env",
    "evaluate_with_rollout",
    "play_greedy_episodes",
]


@dataclass
class EvalResult:
    """Per-episode figures of one evaluation."""

    returns: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    initial_values: list[float] = field(default_factory=list)  # max_a Q(s_0, a) per episode

    def extend(self, other: EvalResult, limit: int | None = None) -> None:
        """Add ``other``'s episodes (its first ``limit`` of them, if given) to these."""
        self.returns += other.returns[:limit]
        self.lengths += other.lengths[:limit]
        self.initial_values += other.initial_values[:limit]

    @property
    def mean(self) -> float:
        return float(torch.tensor(self.returns).mean())

    @property
    def std(self) -> float:
        return float(torch.tensor(self.returns).std(unbiased=False))

    @property
    def initial_value(self) -> float:
        return float(torch.tensor(self.initial_values).mean())


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


# the transforms make_env puts on a vector env: the direct path below knows what each one does
_KNOWN_TRANSFORMS = (
    VecGymEnvTransform,  # the autoreset bridge: the direct path reads Gymnasium's own autoreset
    StepCounter,  # episode statistics: counted here
    RewardSum,
    DoubleToFloat,  # casts to float32: done here
    DTypeCastTransform,
    ObservationNorm,  # applied here, as the TorchRL transform it is
    StepDeadline,  # each Gymnasium step bounded here by its StepAlarm
)


def _vector_env_behind(env: EnvBase) -> gym.vector.VectorEnv | None:
    """The Gymnasium vector env behind ``env``, if :func:`evaluate` may step it directly."""
    if not isinstance(env, TransformedEnv):
        return None
    if not all(isinstance(t, _KNOWN_TRANSFORMS) for t in env.transform):
        return None
    if not isinstance(env.base_env, GymWrapper):
        return None
    vector_env = gym_env(env)
    if not isinstance(vector_env, gym.vector.VectorEnv):
        return None
    if vector_env.metadata.get("autoreset_mode") != gym.vector.AutoresetMode.SAME_STEP:
        return None
    return vector_env


def _action_values(
    actor: TensorDictModuleBase, norms: list[ObservationNorm]
) -> Callable[[torch.Tensor], torch.Tensor]:
    """``observations [E, obs_dim] -> action_value`` of ``actor``, with the env's norms first.

    The Q-network itself when ``actor`` is a ``QValueActor`` (its first module maps
    ``observation`` to ``action_value``) and no norm applies; else the whole actor (a
    ``DistributionalQValueActor`` adds a log-softmax over atoms), called on a ``TensorDict`` of
    the observation.
    """
    plain = isinstance(actor, QValueActor) and not isinstance(actor, DistributionalQValueActor)
    value = actor.module[0] if plain else None
    if (
        not norms
        and isinstance(value, TensorDictModule)
        and value.in_keys == [OBSERVATION_KEY]
        and value.out_keys == ["action_value"]
    ):
        return value.module

    def through_actor(observation: torch.Tensor) -> torch.Tensor:
        td = TensorDict({OBSERVATION_KEY: observation}, batch_size=observation.shape[:1])
        for norm in norms:
            td = norm(td)
        return actor(td)["action_value"]

    return through_actor


@torch.inference_mode()
def evaluate_on_vector_env(
    actor: TensorDictModuleBase,
    env: TransformedEnv,
    vector_env: gym.vector.VectorEnv,
    max_steps: int,
) -> EvalResult:
    """One greedy episode per env, stepping the Gymnasium vector env with no TensorDict env.

    The same episodes as ``env.rollout`` from a fresh ``reset()``, several times cheaper per
    step: TorchRL's env step (its wrapper and transforms) is skipped, and the Q-network is
    called on the observation tensor (:func:`_action_values`). Each call continues the envs' seeded
    random streams (Gymnasium's ``reset()`` without a seed).
    """
    action_values = _action_values(
        actor, [t for t in env.transform if isinstance(t, ObservationNorm)]
    )
    # the env's StepDeadline, if any, bounds the Gymnasium steps played here
    deadline = next((t.seconds for t in env.transform if isinstance(t, StepDeadline)), None)
    device = next(actor.parameters()).device  # Gymnasium's observations are on the CPU

    def q_values(observation: torch.Tensor) -> torch.Tensor:  # [E, obs_dim] -> [E, A] on CPU
        return expected_action_values(actor, action_values(observation.to(device))).cpu()

    with set_exploration_type(ExplorationType.DETERMINISTIC):
        return play_greedy_episodes(
            vector_env,
            q_values,
            max_steps,
            step_timeout=deadline,
        )


@torch.inference_mode()
def play_greedy_episodes(
    vector_env: gym.vector.VectorEnv,
    q_values: Callable[[torch.Tensor], torch.Tensor],
    max_steps: int,
    seed: int | None = None,
    step_timeout: float | None = None,
) -> EvalResult:
    """Each env's first episode, greedy on ``q_values`` (obs ``[E, obs_dim]`` -> ``[E, A]``).

    The evaluation protocol of a run and of the benchmark's peers alike: the Gymnasium vector
    env is reset (with ``seed`` if given, else continuing its seeded random streams), stepped
    until every env has ended one episode or ``max_steps``, and only each env's first episode
    counts (Gymnasium's same-step autoreset starts the next one at once). ``step_timeout``
    bounds each reset and step (:class:`~trl_cartpole.envs.faults.StepAlarm`).
    """
    alarm = StepAlarm(step_timeout)
    num_envs = vector_env.num_envs
    returns = np.zeros(num_envs)  # [E]
    lengths = np.zeros(num_envs, dtype=np.int64)  # [E]
    running = np.ones(num_envs, dtype=bool)  # [E] still in its first episode
    initial_q = None
    with alarm:
        obs, _ = vector_env.reset(seed=seed)  # obs: [E, obs_dim]
    for _ in range(max_steps):
        q = q_values(torch.as_tensor(obs, dtype=torch.float32))  # [E, num_actions]
        if initial_q is None:
            initial_q = q
        with alarm:
            obs, reward, terminated, truncated, _ = vector_env.step(q.argmax(-1).numpy())
        returns += reward * running
        lengths += running
        running &= ~(terminated | truncated)
        if not running.any():
            break
    return EvalResult(
        returns=returns.tolist(),
        lengths=lengths.tolist(),
        initial_values=initial_q.max(-1).values.tolist(),
    )


def evaluate(
    actor: TensorDictModuleBase, env: EnvBase, max_steps: int = 10_000, epsilon: float = 0.0
) -> EvalResult:
    """Play one greedy episode (``ExplorationType.DETERMINISTIC``) in each env of ``env``.

    ``env`` is a batched env of batch size ``[E]`` (``make_env(..., num_envs=E)``): the rollout
    runs until every env has finished one episode (or ``max_steps``), and only each env's first
    episode counts. ``actor`` must write ``action_value`` (a ``QValueActor`` or a
    ``DistributionalQValueActor``). With ``epsilon > 0`` each action is replaced by a uniform
    random one with that probability (the Atari protocol's epsilon = 0.05 evaluation).

    A greedy evaluation on a :func:`make_env` vector env steps the Gymnasium vector env
    directly (:func:`evaluate_on_vector_env`); a single env, another env, or ``epsilon > 0``
    go through TorchRL's ``env.rollout``.
    """
    vector_env = _vector_env_behind(env)
    if vector_env is not None and epsilon == 0:
        return evaluate_on_vector_env(actor, env, vector_env, max_steps)
    return evaluate_with_rollout(actor, env, max_steps, epsilon)


@torch.no_grad()
def evaluate_with_rollout(
    actor: TensorDictModuleBase, env: EnvBase, max_steps: int, epsilon: float
) -> EvalResult:
    """:func:`evaluate` through TorchRL's env steps (any env, any epsilon).

    The steps of ``env.rollout(max_steps, policy, break_when_all_done=True)``: each env is
    stepped until its first episode ends, then left (TorchRL's partial step), until all have
    ended. Only each env's return, length and first action values are kept, not the trajectory:
    a batch of Atari games near ALE's 108 000-frame cap would hold gigabytes of frames.
    """
    policy = actor
    if epsilon > 0:
        policy = TensorDictSequential(actor, EpsilonGreedy(env.action_spec, epsilon))
    shape = env.batch_size  # [E], or [] for a single env
    returns = torch.zeros(shape.numel())  # [E]
    lengths = torch.zeros(shape.numel(), dtype=torch.long)  # [E]
    running = torch.ones(shape.numel(), dtype=torch.bool)  # [E] still in its first episode
    initial_q = None
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        tensordict = env.reset()
        for step in range(max_steps):
            tensordict.update(policy(tensordict))
            if initial_q is None:
                values = tensordict["action_value"]  # [E, num_actions(, atoms)] or unbatched
                initial_q = expected_action_values(
                    actor, values.reshape(-1, *values.shape[len(shape) :])
                )
            tensordict = env.step(tensordict)
            reward = tensordict["next", "reward"].reshape(-1)  # [E]
            done = tensordict["next", "done"].reshape(-1)  # [E]
            returns += reward * running
            lengths += running
            running &= ~done
            if not running.any() or step == max_steps - 1:
                break
            tensordict = next_step_input(env, tensordict)
            tensordict.set(PARTIAL_STEP_KEY, running.view(shape))  # the ended envs wait
    return EvalResult(
        returns=returns.tolist(),
        lengths=lengths.tolist(),
        initial_values=initial_q.max(-1).values.tolist(),
    )


@dataclass
class EvalCurve:
    """The periodic evaluations of a run, one entry each."""

    frames: list[int] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)  # training seconds, evaluation excluded
    returns: list[float] = field(default_factory=list)  # greedy mean return
    initial_values: list[float] = field(default_factory=list)  # mean max_a Q(s_0, a)
    rss_mb: list[float | None] = field(default_factory=list)  # resident memory (MiB) then


@dataclass
class Evaluation:
    """One periodic evaluation: what :meth:`Evaluator.run` returns for the loop to dispatch."""

    frames: int  # frames collected when it ran
    seconds: float  # training seconds when it ran (the clock stopped while it plays)
    result: EvalResult
    best_return: float  # the best greedy mean so far, this one included
    new_best: bool  # this one is the best so far (its weights are kept)
    solved: bool  # the greedy mean reached the solve threshold
    stop: bool  # solved, and the run stops when solved


@dataclass
class Candidate:
    """A policy the evaluator keeps: its weights and the periodic evaluation that found it."""

    frames: int  # frames collected when it was evaluated
    eval_return_mean: float  # its periodic greedy mean
    state: dict[str, torch.Tensor]  # the network's state_dict then


class Evaluator:
    """Greedy evaluations every ``interval_frames``; keeps the best weights and the solve point.

    ``play()`` plays the evaluation episodes (``evaluate(actor, env, max_steps)`` in a run, a
    peer's own greedy episodes in the benchmark) and ``network`` is what plays them: its
    ``state_dict`` is kept at each new best, and with ``candidates=K`` the K best policies so
    far are kept (:attr:`candidates`, best first, the earlier one first on a tie; the run plays
    them again before its final evaluation, :mod:`trl_cartpole.run.best_policy`). :meth:`run`
    only evaluates and keeps score; what follows (logging, the progress bar, the plot, saving
    the best policy) is the caller's.
    """

    def __init__(
        self,
        play: Callable[[], EvalResult],
        network: torch.nn.Module,
        interval_frames: int,
        threshold: float | None,
        stop_when_solved: bool = True,
        candidates: int = 1,
    ) -> None:
        self.play, self.network = play, network
        self.max_candidates = candidates
        self.candidates: list[Candidate] = []  # the best policies so far, best first
        self.interval_frames = interval_frames
        self.threshold, self.stop_when_solved = threshold, stop_when_solved
        self.best_return = -float("inf")
        self.best_state: dict[str, torch.Tensor] | None = None
        self.frames_to_solve: int | None = None
        self.seconds_to_solve: float | None = None
        self.last_eval_frame = -1
        self.curve = EvalCurve()

    def due(self, progress: Progress) -> bool:
        """Whether ``interval_frames`` frames have passed since the last evaluation."""
        return progress.frames - max(self.last_eval_frame, 0) >= self.interval_frames

    def run(self, progress: Progress) -> Evaluation:
        """Evaluate greedily with the training clock stopped; keep the weights if the best."""
        running = progress.clock.running
        progress.clock.pause()
        result = self.play()
        frames, seconds = progress.frames, progress.clock.seconds
        self.last_eval_frame = frames
        self.curve.frames.append(frames)
        self.curve.seconds.append(round(seconds, 3))
        self.curve.returns.append(result.mean)
        self.curve.initial_values.append(result.initial_value)
        self.curve.rss_mb.append(resident_mb())
        new_best = result.mean > self.best_return
        if new_best:
            self.best_return = result.mean
            self.best_state = copy.deepcopy(self.network.state_dict())
        self._keep_candidate(frames, result.mean, new_best)
        solved = self.threshold is not None and result.mean >= self.threshold
        if solved and self.frames_to_solve is None:
            self.frames_to_solve, self.seconds_to_solve = frames, seconds
        if running:
            progress.clock.start()
        stop = solved and self.stop_when_solved
        return Evaluation(frames, seconds, result, self.best_return, new_best, solved, stop)

    def _keep_candidate(self, frames: int, mean: float, new_best: bool) -> None:
        """Keep this evaluation's weights among the ``max_candidates`` best (a new best's
        weights are the copy just kept as ``best_state``: one copy, not two)."""
        kept = self.candidates
        if len(kept) >= self.max_candidates and mean <= kept[-1].eval_return_mean:
            return
        state = self.best_state if new_best else copy.deepcopy(self.network.state_dict())
        place = sum(candidate.eval_return_mean >= mean for candidate in kept)
        kept.insert(place, Candidate(frames, mean, state))
        del kept[self.max_candidates :]

    def load_best(self) -> None:
        """Put the best weights seen into the network."""
        self.network.load_state_dict(self.best_state)

    def keep(self, candidate: Candidate) -> None:
        """Make ``candidate`` the policy the run keeps (its weights go into the network)."""
        self.best_state = candidate.state
        self.network.load_state_dict(candidate.state)

    def state_dict(self) -> dict[str, Any]:
        return {
            "best_return": self.best_return,
            "best_state": self.best_state,
            "candidates": {
                "frames": [candidate.frames for candidate in self.candidates],
                "returns": [candidate.eval_return_mean for candidate in self.candidates],
                "states": [candidate.state for candidate in self.candidates],
            },
            "frames_to_solve": self.frames_to_solve,
            "seconds_to_solve": self.seconds_to_solve,
            "last_eval_frame": self.last_eval_frame,
            "curve": asdict(self.curve),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.best_return, self.best_state = state["best_return"], state["best_state"]
        self.frames_to_solve = state["frames_to_solve"]
        self.seconds_to_solve = state["seconds_to_solve"]
        self.last_eval_frame = state["last_eval_frame"]
        for name, values in state["curve"].items():
            getattr(self.curve, name)[:] = values
        kept = state["candidates"]
        self.candidates = [
            Candidate(frames, mean, weights)
            for frames, mean, weights in zip(
                kept["frames"], kept["returns"], kept["states"], strict=True
            )
        ]
        self.candidates = self.candidates[: self.max_candidates]
