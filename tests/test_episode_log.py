"""An env whose state is not plain data resumes by playing its logged episode again."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torchrl.envs.utils import step_mdp

from trl_cartpole.compat import gym_env
from trl_cartpole.envs import episode_log
from trl_cartpole.envs.episode_log import EpisodeLog, records_episodes
from trl_cartpole.parts.env import make_env
from trl_cartpole.store.env_state import env_snapshot, restore_env_snapshot


def _lander(num_envs: int, seed: int):
    return make_env(
        "LunarLander-v3", num_envs=num_envs, seed=seed, categorical_action_encoding=True
    )


def _play(env, td, steps: int, generator: torch.Generator):
    """``steps`` random actions from ``td``; the last step's tensordict and the episodes ended."""
    ended = 0
    for _ in range(steps):
        td["action"] = torch.randint(0, 4, env.action_spec.shape, generator=generator)
        td = env.step(td)
        ended += int(td["next", "done"].sum())
        td = step_mdp(td)
    return td, ended


def test_which_envs_log_their_episodes():
    assert records_episodes("LunarLander-v3")
    assert not records_episodes("CartPole-v1") and not records_episodes("Acrobot-v1")
    assert isinstance(gym_env(_lander(1, 0)), EpisodeLog)
    assert all(isinstance(e, EpisodeLog) for e in gym_env(_lander(2, 0)).envs)
    assert not isinstance(gym_env(make_env("CartPole-v1")), EpisodeLog)


@pytest.mark.parametrize("num_envs", [1, 3])
def test_a_fresh_env_replays_into_the_same_state(num_envs):
    generator = torch.Generator().manual_seed(0)
    env = _lander(num_envs, seed=5)
    td, ended = _play(env, env.reset(), 150, generator)
    assert num_envs == 1 or ended > 0  # the vector env's episodes ended and began again
    snapshot = env_snapshot(env)
    assert set(snapshot) == {"replay"}
    fresh = _lander(num_envs, seed=99)  # another seed: only the replay makes them equal
    fresh.reset()
    assert restore_env_snapshot(fresh, snapshot)
    twin = td.clone()
    for _ in range(100):  # the same actions from here: the same observations and rewards
        action = torch.randint(0, 4, env.action_spec.shape, generator=generator)
        td["action"], twin["action"] = action, action.clone()
        a, b = env.step(td), fresh.step(twin)
        assert torch.equal(a["next", "observation"], b["next", "observation"])
        assert torch.equal(a["next", "reward"], b["next", "reward"])
        assert torch.equal(a["next", "done"], b["next", "done"])
        td, twin = step_mdp(a), step_mdp(b)


def test_a_replay_that_does_not_reach_the_logged_state_is_refused():
    env = _lander(2, seed=5)
    _play(env, env.reset(), 20, torch.Generator().manual_seed(0))
    snapshot = env_snapshot(env)
    snapshot["replay"]["envs"][1]["observation"] = snapshot["replay"]["envs"][1]["observation"] + 1
    fresh = _lander(2, seed=5)
    fresh.reset()
    assert not restore_env_snapshot(fresh, snapshot)


def test_an_episode_too_long_to_log_is_not_replayed(monkeypatch):
    monkeypatch.setattr(episode_log, "MAX_LOGGED_STEPS", 5)
    env = _lander(1, seed=5)
    _play(env, env.reset(), 4, torch.Generator().manual_seed(0))
    assert env_snapshot(env) is not None
    _play(env, env.reset(), 6, torch.Generator().manual_seed(0))
    assert env_snapshot(env) is None  # new episodes on resume, as for any other such env


@pytest.mark.parametrize("seed", [7, None])  # a reset given a seed; one of an env never seeded
def test_a_single_gymnasium_env_replays_its_episode(seed):
    import gymnasium as gym

    actions = np.random.default_rng(0).integers(0, 4, size=40)
    logged = EpisodeLog(gym.make("LunarLander-v3"))
    logged.reset(seed=seed)
    for action in actions:
        logged.step(int(action))
    record = logged.record()
    assert record["seed"] == seed and (record["rng"] is None) == (seed is not None)
    assert len(record["actions"]) == 40
    fresh = EpisodeLog(gym.make("LunarLander-v3"))
    assert fresh.replay(record)
    for action in (0, 2, 3):  # and it goes on as the logged env does
        a, b = logged.step(action), fresh.step(action)
        assert np.array_equal(a[0], b[0]) and a[1] == b[1]
