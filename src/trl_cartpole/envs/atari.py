"""Atari games (ALE) through TorchRL transforms: the standard DQN preprocessing.

Mnih et al. (2015, "Human-level control through deep reinforcement learning", Methods) and
Machado et al. (2018, "Revisiting the Arcade Learning Environment") fixed how a DQN sees a
game; Gymnasium's ``AtariPreprocessing`` + ``FrameStackObservation`` and TorchRL's DQN Atari
example each implement it. Here the base env is ALE's own, made with ``frameskip=1`` and
``obs_type="grayscale"`` (ALE's ``getScreenGrayscale``, the screen Gymnasium's wrapper reads),
then TorchRL transforms, each one documented choice (docs/atari.md lists them and where they
differ from Gymnasium's and TorchRL's example):

1. :class:`NoopStarts`: 1 to ``noop_max`` NOOP frames after each reset (Gymnasium's
   ``noop_max``; TorchRL's ``NoopResetEnv`` plays random actions instead).
2. :class:`MaxPoolFrameSkip`: each action held for ``frame_skip`` frames, the rewards summed,
   the observation the pixel-wise max of the last two frames (the sprites Atari draws every
   other frame); the skip stops at the game's end.
3. :class:`ResizeFrame`: the ``[210, 160]`` screen to ``[1, 84, 84]`` uint8 with OpenCV's
   ``INTER_AREA``, as Gymnasium's wrapper (TorchRL's ``Resize`` needs torchvision, which does
   not install beside torch's CPU wheel), under ``"pixels"``.
4. :class:`FireOnReset`: where the game has a FIRE action (Breakout's ball waits for it),
   ``fire_steps`` (2) FIRE steps after each reset and each lost life (OpenAI Baselines'
   ``FireResetEnv``; two, so that sticky actions do not swallow the serve).
5. TorchRL's ``EndOfLifeTransform(done_key="terminated")``: ``("next", "end-of-life")`` marks
   a lost life (or the game's end); the env plays on, so an episode in every report and
   evaluation is the whole game. The learner reads a lost life as the end of its episode
   through the replay buffer's :class:`LearnerView`, which also clips the rewards to their
   sign, so the env's ``episode_reward`` is the game's own score.
6. TorchRL's ``StepCounter``, ``RewardSum`` and ``CatFrames(4, dim=-3)``: the last four
   frames ``[4, 84, 84]`` uint8, the first repeated after a reset (Gymnasium's
   ``padding_type="reset"``).

Each game is capped at ALE's ``max_num_frames_per_episode`` (108 000 frames, 30 minutes of
play: Machado et al.; ``eval.max_steps`` must allow its 27 000 agent steps for an evaluation to
play it whole, as the Breakout preset's does).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.data.tensor_specs import Bounded, TensorSpec
from torchrl.envs import (
    CatFrames,
    EndOfLifeTransform,
    GymWrapper,
    ObservationTransform,
    RewardSum,
    StepCounter,
    TransformedEnv,
)
from torchrl.envs.transforms import Transform

from trl_cartpole.compat import gym_env, parent_reset, parent_step, set_missing_tolerance
from trl_cartpole.envs.ids import register_atari_games
from trl_cartpole.envs.pixels import PIXELS_KEY

__all__ = [
    "ATARI_DEFAULTS",
    "EOL_KEY",
    "FireOnReset",
    "LastAction",
    "LearnerView",
    "MaxPoolFrameSkip",
    "NoopStarts",
    "ResizeFrame",
    "atari_transforms",
    "fire_action",
    "make_atari_env",
]

EOL_KEY = "end-of-life"  # TorchRL's EndOfLifeTransform's default key
SCREEN_KEY = "observation"  # the grayscale screen [210, 160] of GymWrapper(obs_type="grayscale")
# The standard preprocessing's values (Mnih et al. 2015; Machado et al. 2018)
ATARI_DEFAULTS: dict[str, Any] = {
    "noop_max": 30,
    "frame_skip": 4,
    "screen_size": 84,
    "frames": 4,
    "fire_on_reset": True,
    "fire_steps": 2,
}


class NoopStarts(Transform):
    """After each reset, NOOP (action 0) for a number of frames drawn uniformly from
    ``[1, noop_max]`` (Mnih et al. 2015: up to 30; Gymnasium's and Baselines' range), so
    games do not all start alike. The count is drawn from the Gymnasium env's ``np_random``
    (seeded with the env, as Gymnasium's wrapper draws it); a game that ends during them is
    reset again."""

    def __init__(self, noop_max: int = 30) -> None:
        super().__init__()
        self.noop_max = int(noop_max)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase):
        parent = self.parent
        rng = gym_env(parent).unwrapped.np_random  # the game's own, seeded with the env
        noops = int(rng.integers(1, self.noop_max + 1)) if self.noop_max else 0
        state = tensordict_reset
        for _ in range(noops):
            action = parent.full_action_spec.zero()  # NOOP is action 0 in every ALE game
            stepped = parent_step(parent, state.clone(False).update(action))
            if stepped.get("done").any():
                state = parent_reset(parent, state.clone(False))
                continue
            state = stepped.exclude("reward")
        return tensordict_reset.update(state.exclude("reward", "action"))


class MaxPoolFrameSkip(Transform):
    """Hold each action for ``frame_skip`` frames: the rewards summed, the observation the
    pixel-wise max of the last two frames (Mnih et al. 2015: Atari draws some sprites every
    other frame). The skip stops at the game's end (``done``); TorchRL's
    ``FrameSkipTransform`` does the repeat without the max."""

    def __init__(self, frame_skip: int = 4, screen_key: str = SCREEN_KEY) -> None:
        if frame_skip < 1:
            raise ValueError(f"frame_skip={frame_skip} must be >= 1")
        super().__init__()
        self.frame_skip = int(frame_skip)
        self.screen_key = screen_key

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase):
        parent = self.parent
        reward = next_tensordict.get("reward")
        previous = None  # the frame before the last
        for _ in range(self.frame_skip - 1):
            if next_tensordict.get("done").any():
                break
            previous = next_tensordict.get(self.screen_key)
            next_tensordict = parent_step(parent, tensordict)
            reward = reward + next_tensordict.get("reward")
        if previous is not None:
            last = next_tensordict.get(self.screen_key)
            next_tensordict.set(self.screen_key, torch.maximum(previous, last))
        return next_tensordict.set("reward", reward)

    def forward(self, tensordict):
        raise RuntimeError("MaxPoolFrameSkip steps its env: append it to a TransformedEnv")


class ResizeFrame(ObservationTransform):
    """The grayscale screen ``[*B, H, W]`` uint8 to ``[*B, 1, size, size]`` uint8 under
    ``"pixels"``, with OpenCV's ``INTER_AREA`` (pixel-area averaging), as Gymnasium's
    ``AtariPreprocessing`` resizes."""

    def __init__(self, size: int = 84, in_key: str = SCREEN_KEY, out_key: str = PIXELS_KEY):
        super().__init__(in_keys=[in_key], out_keys=[out_key])
        self.size = int(size)

    def _apply_transform(self, screen: torch.Tensor) -> torch.Tensor:
        import cv2

        frames = screen.reshape(-1, *screen.shape[-2:]).cpu().numpy()  # [N, H, W]
        resized = np.stack(
            [cv2.resize(f, (self.size, self.size), interpolation=cv2.INTER_AREA) for f in frames]
        )  # [N, size, size]
        out = torch.from_numpy(resized).reshape(*screen.shape[:-2], 1, self.size, self.size)
        return out.to(screen.device)

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        out = super()._call(next_tensordict)
        return out.exclude(*(k for k in self.in_keys if k not in self.out_keys))

    def _reset(self, tensordict, tensordict_reset):
        with set_missing_tolerance(self, True):
            return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: TensorSpec) -> TensorSpec:
        screen = observation_spec[self.in_keys[0]]
        shape = (*screen.shape[:-2], 1, self.size, self.size)
        del observation_spec[self.in_keys[0]]
        observation_spec[self.out_keys[0]] = Bounded(
            0, 255, shape=shape, dtype=torch.uint8, device=screen.device
        )
        return observation_spec


class FireOnReset(Transform):
    """``steps`` steps of FIRE after each reset and after each lost life that does not end the
    game (OpenAI Baselines' ``FireResetEnv`` under its ``EpisodicLifeEnv``, which resets at each
    lost life): a game such as Breakout waits for FIRE to serve, and a greedy policy that
    never presses it would wait until the game's frame cap. ``fire_action`` is FIRE's index
    in the game's action set (:func:`fire_action`). After a lost life the FIRE steps' rewards
    join the step's; after a reset they are dropped, as the NOOPs' are.

    Why two steps by default: with sticky actions (Machado et al. 2018; Gymnasium's v5 games)
    each frame repeats the previous frame's action with probability 0.25, so all 4 frames of
    one FIRE step are swallowed once in 256 (0.25^4) and the game waits; a second step leaves
    it once in 65 536. Measured on Breakout: 3 of 100 greedy games of a trained policy with
    one FIRE step waited out ALE's 108 000-frame cap (docs/atari.md)."""

    def __init__(self, fire_action: int, steps: int = 2) -> None:
        if steps < 1:
            raise ValueError(f"steps={steps} must be >= 1 (leave FireOnReset out for none)")
        super().__init__()
        self.fire_action = int(fire_action)
        self.steps = int(steps)
        # the lives at the last step, a buffer so the env's state_dict (a checkpoint) holds it
        self.register_buffer("lives_before", torch.tensor(-1))

    def _fire(self, state: TensorDictBase) -> TensorDictBase:
        """``steps`` FIRE steps from ``state`` (fewer if the game ends), rewards summed."""
        parent = self.parent
        action = parent.full_action_spec.zero()
        key = parent.action_key
        action.set(key, torch.full_like(action.get(key), self.fire_action))
        stepped = parent_step(parent, state.clone(False).update(action))
        reward = stepped.get("reward")
        for _ in range(self.steps - 1):
            if stepped.get("done").any():
                break
            stepped = parent_step(parent, state.clone(False).update(action))
            reward = reward + stepped.get("reward")
        return stepped.set("reward", reward)

    def _lives(self) -> int:
        return int(gym_env(self.parent).unwrapped.ale.lives())

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase):
        stepped = self._fire(tensordict_reset)
        self.lives_before.fill_(self._lives())
        if stepped.get("done").any():  # the game ended on its first moves: start again
            restarted = parent_reset(self.parent, tensordict_reset.clone(False))
            self.lives_before.fill_(self._lives())  # the new game's, not the ended one's
            return restarted
        return tensordict_reset.update(stepped.exclude("reward", "action"))

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase):
        lives = self._lives()
        lost = lives < int(self.lives_before)
        self.lives_before.fill_(lives)
        if not lost or next_tensordict.get("done").any():
            return next_tensordict
        fired = self._fire(next_tensordict)
        fired.set("reward", next_tensordict.get("reward") + fired.get("reward"))
        self.lives_before.fill_(self._lives())
        return fired


class LastAction(gym.Wrapper):
    """Remembers the action of the game's last frame (``last_action``, an index of its action
    set; None before the first), which a checkpoint stores with the game.

    ALE's ``cloneState`` holds the emulator and the random generator of sticky actions, but not
    the action a sticky frame repeats (the last frame's): a game restored into an env whose last
    action was another repeats that one on its first sticky frame and plays on differently.
    :func:`trl_cartpole.store.env_state` puts this action back with the state. It is the action
    asked for; the frame's own action differs only when all frames of a step stuck to the one
    before, 0.25^4 = 1 step in 256 with Gymnasium's sticky actions."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.last_action: int | None = None

    def step(self, action: Any):
        self.last_action = int(action)
        return self.env.step(action)

    def reset(self, **kwargs: Any):
        self.last_action = None
        return self.env.reset(**kwargs)


def fire_action(gym_env: Any) -> int | None:
    """FIRE's index in the game's action set, or None when the game has none."""
    meanings = gym_env.unwrapped.get_action_meanings()
    return meanings.index("FIRE") if "FIRE" in meanings else None


class LearnerView(Transform):
    """What the learner learns from, as a replay buffer's transform (applied when a batch is
    stored, never to the env's reports): a lost life ends the learner's episode
    (``("next", "terminated")`` and ``("next", "done")`` set where ``("next",
    "end-of-life")`` is, so an n-step window stops there and does not bootstrap; Mnih et al.
    2015), and each reward is clipped to its sign (``clip_rewards``)."""

    def __init__(self, life_loss_ends: bool = True, clip_rewards: bool = True) -> None:
        super().__init__()
        self.life_loss_ends = life_loss_ends
        self.clip_rewards = clip_rewards

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        out = tensordict.clone(False)
        following = out.get("next").clone(False)
        if self.life_loss_ends and EOL_KEY in following.keys():  # noqa: SIM118 (a TensorDict)
            lost = following.get(EOL_KEY)
            for key in ("terminated", "done"):
                following.set(key, following.get(key) | lost)
        if self.clip_rewards:
            following.set("reward", following.get("reward").sign())
        out.set("next", following)
        return out

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return tensordict


def atari_transforms(
    gym_env: Any,
    noop_max: int = 30,
    frame_skip: int = 4,
    screen_size: int = 84,
    frames: int = 4,
    fire_on_reset: bool = True,
    fire_steps: int = 2,
) -> list[Transform]:
    """The transforms of the module docstring, in order, for ``gym_env`` (an ALE env made
    with ``frameskip=1, obs_type="grayscale"``)."""
    transforms: list[Transform] = []
    if noop_max:
        transforms.append(NoopStarts(noop_max))
    if frame_skip > 1:
        transforms.append(MaxPoolFrameSkip(frame_skip))
    transforms.append(ResizeFrame(screen_size))  # pixels [1, size, size] uint8
    fire = fire_action(gym_env) if fire_on_reset else None
    if fire is not None:
        transforms.append(FireOnReset(fire, fire_steps))
    transforms += [
        EndOfLifeTransform(eol_key=EOL_KEY, done_key="terminated"),
        StepCounter(),
        RewardSum(),  # the game's own score: rewards are clipped for the learner only
    ]
    if frames > 1:
        transforms.append(CatFrames(N=frames, dim=-3, in_keys=[PIXELS_KEY]))  # [frames, s, s]
    return transforms


def make_atari_env(
    env_name: str = "ALE/Breakout-v5",
    device: str | torch.device = "cpu",
    *,
    seed: int | None = None,
    preprocessing: Mapping[str, Any] | None = None,
    **kwargs: Any,
) -> TransformedEnv:
    """TorchRL's ``TransformedEnv`` of an ALE game with the standard preprocessing.

    The call form of TorchRL's ``GymEnv``: ``env_name`` and ``device``, then keywords; every
    other keyword goes to ``gymnasium.make`` (ALE's own options: ``repeat_action_probability``
    (sticky actions, Gymnasium's v5 default 0.25), ``full_action_space``, ``mode``,
    ``difficulty``...), except ``frameskip`` and ``obs_type``, which the preprocessing sets
    (``frameskip=1``: the skip is :class:`MaxPoolFrameSkip`'s).

    Example::

        >>> from trl_cartpole.envs.atari import make_atari_env
        >>> env = make_atari_env("ALE/Breakout-v5", seed=0)
        >>> env.reset()["pixels"].shape
        torch.Size([4, 84, 84])

    :param preprocessing: the keywords of :func:`atari_transforms` (``noop_max``,
        ``frame_skip``, ``screen_size``, ``frames``, ``fire_on_reset``, ``fire_steps``); left out:
        :data:`ATARI_DEFAULTS`.
    :returns: ``TransformedEnv(GymWrapper(LastAction(gymnasium.make(env_name,
        frameskip=1, obs_type="grayscale", ...))), <the transforms>)``: ``"pixels"``
        ``[frames, 84, 84]`` uint8, categorical actions.
    """
    for fixed in ("frameskip", "obs_type"):
        if fixed in kwargs:
            raise ValueError(
                f"{fixed}: set by the preprocessing (frameskip=1, obs_type='grayscale'); give "
                "preprocessing={'frame_skip': k} for another skip"
            )
    register_atari_games()
    settings = {**ATARI_DEFAULTS, **(preprocessing or {})}
    gym_env = LastAction(gym.make(env_name, frameskip=1, obs_type="grayscale", **kwargs))
    base = GymWrapper(gym_env, device=device, categorical_action_encoding=True)
    env = TransformedEnv(base)
    for transform in atari_transforms(gym_env, **settings):
        env.append_transform(transform)
    if seed is not None:
        env.set_seed(seed)
    return env
