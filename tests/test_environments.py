"""Any discrete-action Gymnasium env by config alone: presets, custom envs, refusals, norm."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from trl_cartpole.config.schema import EnvConfig, to_config
from trl_cartpole.envs.ids import resolve_env_id, solve_threshold
from trl_cartpole.errors import ConfigError
from trl_cartpole.parts.env import MIN_OBSERVATION_SCALE, make_env
from trl_cartpole.parts.models import make_q_actor
from trl_cartpole.policy.load import evaluate_checkpoint
from trl_cartpole.run.envs import estimate_observation_norm, make_env_from_config
from trl_cartpole.run.evaluation import evaluate
from trl_cartpole.run.from_config import build_actor
from trl_cartpole.run.training import train
from trl_cartpole.store.checkpoint import read_observation_norm

from .conftest import ROOT, SMOKE_OVERRIDES, run_script

EXAMPLES = ROOT / "examples"
# Corridor trains to its goal from config alone: 8 cells, +1 at the far end (examples/corridor.py).
CORRIDOR_OVERRIDES = [
    "env.id=corridor:Corridor",
    "eval.solve_threshold=1",
    "collector.total_frames=4000",
    "eval.interval_frames=500",
    "eval.episodes=5",
    "eval.final_episodes=10",
    "logger.progress_bar=false",
    "logger.plots=false",
]


@pytest.fixture
def examples_on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))


@pytest.fixture
def fresh_registry(monkeypatch):
    """Ids registered by a test are dropped afterwards (Gymnasium's registry is global)."""
    monkeypatch.setattr(gym.envs.registration, "registry", dict(gym.registry))
    monkeypatch.setattr(gym, "registry", gym.envs.registration.registry)


@pytest.mark.parametrize(
    ("preset", "env_id", "obs_dim", "actions"),
    [
        ("acrobot", "Acrobot-v1", 6, 3),
        ("mountaincar", "MountainCar-v0", 2, 3),
        ("lunarlander", "LunarLander-v3", 8, 4),
    ],
)
def test_env_presets_compose_and_build(compose, preset, env_id, obs_dim, actions):
    cfg = to_config(compose(f"env={preset}"))
    assert cfg.env.id == env_id
    env = make_env_from_config(
        cfg.env, 0, num_envs=2, observation_norm={"loc": [0.0] * obs_dim, "scale": [1.0] * obs_dim}
    )
    assert env.observation_spec["observation"].shape == (2, obs_dim)
    assert env.action_spec.space.n == actions
    env.close()


def test_env_preset_wins_over_the_algo_defaults_it_sets(compose):
    cfg = to_config(compose("env=lunarlander"))
    # the default (algo=dqn) has batch 512, lr 4e-3 and 128-128
    assert cfg.buffer.batch_size == 64 and cfg.optim.lr == 6.2e-4
    assert cfg.network.num_cells == [256, 256]
    cfg = to_config(compose("env=lunarlander", "algo=dueling"))  # a variant switch combines
    assert cfg.network.head == "dueling" and cfg.buffer.batch_size == 64
    cfg = to_config(compose("env=acrobot", "algo=noisy"))
    assert cfg.exploration.schedule == "none" and cfg.buffer.batch_size == 128
    assert cfg.optim.lr == 2.75e-3 and cfg.target_updater.value_network_update_interval == 81
    # a preset leaves the variant switches it does not tune to the algo preset
    assert to_config(compose("env=acrobot", "algo=double")).loss.double_dqn


@pytest.mark.slow  # a run in a fresh interpreter
def test_custom_env_class_trains_from_the_command_line(tmp_path, examples_on_path, fresh_registry):
    proc = run_script(
        "train.py",
        *CORRIDOR_OVERRIDES,
        f"run_dir={tmp_path}",
        env={**os.environ, "PYTHONPATH": str(EXAMPLES)},
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["env_id"] == "corridor:Corridor"
    assert summary["solved"] and summary["final_eval_return_mean"] == 1.0
    # An untrained network does not walk the corridor: the 1.0 was learned.
    env = make_env("corridor:Corridor", seed=1, num_envs=10)
    torch.manual_seed(0)
    assert evaluate(build_actor(to_config({}), env), env, 200).mean < 1.0


def test_ids_registered_by_an_import_named_in_config(tmp_path, monkeypatch, fresh_registry):
    (tmp_path / "my_envs.py").write_text(
        "import gymnasium\n"
        "gymnasium.register('Corridor-v7', entry_point='corridor:Corridor',"
        " kwargs={'length': 5}, reward_threshold=1.0)\n"
    )
    monkeypatch.syspath_prepend(str(EXAMPLES))
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ConfigError, match=r"name the module that registers it in env\.imports"):
        resolve_env_id("Corridor-v7")
    assert resolve_env_id("Corridor-v7", ["my_envs"]) == "Corridor-v7"
    assert resolve_env_id("my_envs:Corridor-v7") == "Corridor-v7"  # Gymnasium's module:id
    assert solve_threshold("Corridor-v7") == 1.0
    env = make_env_from_config(EnvConfig(id="Corridor-v7", imports=["my_envs"], num_envs=1))
    assert env.observation_spec["observation"].shape == (5,)


def test_env_classes_of_the_same_name_in_two_modules_stay_apart(
    tmp_path, monkeypatch, fresh_registry
):
    for module, length in (("corridor_a", 3), ("corridor_b", 6)):
        (tmp_path / f"{module}.py").write_text(
            "from corridor import Corridor as _Base\n"
            "class Corridor(_Base):\n"
            f"    def __init__(self):\n        super().__init__(length={length})\n"
        )
    monkeypatch.syspath_prepend(str(EXAMPLES))
    monkeypatch.syspath_prepend(str(tmp_path))
    assert resolve_env_id("corridor_a:Corridor") == "corridor_a.Corridor"
    assert resolve_env_id("corridor_b:Corridor") == "corridor_b.Corridor"
    shapes = [
        make_env(f"corridor_{m}:Corridor").observation_spec["observation"].shape for m in "ab"
    ]
    assert shapes == [torch.Size([3]), torch.Size([6])]


class _ImageEnv(gym.Env):
    observation_space = gym.spaces.Box(0, 255, (8, 8, 3), dtype="uint8")
    action_space = gym.spaces.Discrete(2)


class _MatrixEnv(gym.Env):
    observation_space = gym.spaces.Box(0, 1, (3, 2))
    action_space = gym.spaces.Discrete(2)


class _DictEnv(gym.Env):
    observation_space = gym.spaces.Dict(
        {"a": gym.spaces.Box(0, 1, (2,)), "b": gym.spaces.Discrete(3)}
    )
    action_space = gym.spaces.Discrete(2)


@pytest.mark.parametrize(
    ("env_id", "message"),
    [
        ("Pendulum-v1", "has continuous actions \\(a Gymnasium Box\\); DQN needs one discrete"),
        ("Blackjack-v1", r"has observation entries \['Discrete', 'Discrete', 'Discrete'\]"),
        ("tests.test_environments:_ImageEnv", r"has image observations of shape \(8, 8, 3\)"),
        ("tests.test_environments:_MatrixEnv", r"has an observation of shape \(3, 2\)"),
        ("tests.test_environments:_DictEnv", r"has observation entries \['a', 'b'\]"),
        ("Taxi-v4", "has a discrete observation"),
        ("Nope-v0", "is not a registered Gymnasium env"),
        ("no_such_module:MyEnv", "cannot import module 'no_such_module'"),
        ("json:JSONDecoder", "neither registers 'JSONDecoder' nor defines a gymnasium.Env"),
    ],
)
@pytest.mark.parametrize("num_envs", [1, 4])  # a vector env is checked before TorchRL wraps it
def test_envs_that_cannot_work_are_refused_in_one_line(env_id, message, num_envs, fresh_registry):
    with pytest.raises(ConfigError, match=message) as caught:
        make_env(env_id, num_envs=num_envs)
    assert "\n" not in str(caught.value)


def test_missing_optional_dependency_names_the_extra(monkeypatch):
    # Make Box2D unimportable and forget Gymnasium's box2d modules, so LunarLander's entry point
    # imports them again the way it does on a machine without the extra.
    monkeypatch.setitem(sys.modules, "Box2D", None)
    for name in [m for m in sys.modules if m.startswith("gymnasium.envs.box2d")]:
        monkeypatch.delitem(sys.modules, name)
    with pytest.raises(
        ConfigError, match=re.escape('pip install torch==2.13.0 -e ".[box2d]"')
    ) as caught:
        make_env("LunarLander-v3")
    assert "LunarLander-v3" in str(caught.value) and "\n" not in str(caught.value)
    assert "swig" not in str(caught.value).lower()  # not Gymnasium's advice beside ours


@pytest.mark.slow  # thousands of random frames
def test_observation_norm_stats_standardise_random_play_and_are_reproducible():
    cfg = EnvConfig(id="MountainCar-v0", normalize_observations=True, normalization_frames=2000)
    stats = estimate_observation_norm(cfg, seed=0)
    assert stats == estimate_observation_norm(cfg, seed=0)
    rng_before = torch.get_rng_state()
    estimate_observation_norm(cfg, seed=1)
    assert torch.equal(torch.get_rng_state(), rng_before)  # the run's random numbers untouched
    # MountainCar: position around -0.5 (the valley), velocity around 0 with a small spread.
    assert -0.7 < stats["loc"][0] < -0.3 and abs(stats["loc"][1]) < 0.005
    assert all(s >= MIN_OBSERVATION_SCALE for s in stats["scale"])
    torch.manual_seed(5)  # the same random actions in both rollouts
    raw = make_env("MountainCar-v0", seed=3).rollout(500, break_when_any_done=False)
    torch.manual_seed(5)
    normed = make_env("MountainCar-v0", seed=3, observation_norm=stats).rollout(
        500, break_when_any_done=False
    )
    loc, scale = torch.tensor(stats["loc"]), torch.tensor(stats["scale"])
    # The transform is (obs - loc) / scale, applied to every observation the agent sees.
    torch.testing.assert_close(normed["observation"], (raw["observation"] - loc) / scale)
    torch.testing.assert_close(
        normed["next", "observation"], (raw["next", "observation"] - loc) / scale
    )


@pytest.mark.slow  # a run, then its checkpoints
def test_observation_norm_travels_with_the_checkpoints(compose, tmp_path):
    summary = train(
        compose(
            *SMOKE_OVERRIDES,
            "env.normalize_observations=true",
            "env.normalization_frames=500",
            f"run_dir={tmp_path}",
            "logger.plots=false",
        )
    )
    stats = estimate_observation_norm(EnvConfig(normalization_frames=500), seed=0)
    best = tmp_path / "checkpoints" / "best"
    assert read_observation_norm(best) == stats
    assert read_observation_norm(tmp_path / "checkpoints" / "last") == stats
    # Evaluating the checkpoint rebuilds the normalised env: the final evaluation repeats.
    result, _ = evaluate_checkpoint(str(best), episodes=summary["final_eval_episodes"])
    assert result.mean == summary["final_eval_return_mean"]


def test_the_guide_shows_the_custom_env_that_the_tests_train():
    guide = (ROOT / "docs" / "guide.md").read_text()
    source = (EXAMPLES / "corridor.py").read_text()
    class_source = source[source.index("class Corridor") :]
    assert class_source.strip() in guide
    assert "PYTHONPATH=examples .venv/bin/python scripts/train.py env.id=corridor:Corridor" in guide


@pytest.mark.slow  # the env benchmark in a subprocess
def test_benchmark_envs_trains_a_preset_and_tabulates_it(tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "benchmarks",
            "envs",
            "--envs",
            "acrobot",
            "--seeds",
            "0",
            "--out",
            str(tmp_path),
            "--",
            "collector.total_frames=1024",
            "eval.interval_frames=512",
            "eval.episodes=2",
            "eval.final_episodes=3",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((tmp_path / "acrobot" / "dqn-seed0" / "summary.json").read_text())
    row = next(line for line in proc.stdout.splitlines() if line.startswith("| acrobot |"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    final = summary["final_eval_return_mean"]
    assert cells[1:3] == ["Acrobot-v1", "every seed >= -80"]
    assert cells[3].endswith("(1 seed)")  # the interquartile mean of one seed is that seed
    assert float(cells[4]) == float(cells[5]) == round(final, 1)  # median, worst seed
    assert cells[7] == ("yes (1/1 seeds)" if final >= -80 else "no (0/1 seeds)")
    assert (tmp_path / "acrobot.png").stat().st_size > 0


class _IntegerVectorEnv(gym.Env):
    """A rank-1 observation of small integers (uint8): trains once cast to float32."""

    observation_space = gym.spaces.Box(0, 255, (3,), dtype=np.uint8)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.steps = 0
        return np.zeros(3, np.uint8), {}

    def step(self, action):
        self.steps += 1
        observation = np.full(3, self.steps, np.uint8)
        return observation, 1.0, False, self.steps >= 10, {}


def test_an_integer_vector_observation_reaches_the_network_as_float32(fresh_registry):
    env = make_env("tests.test_environments:_IntegerVectorEnv", num_envs=2, seed=0)
    actor = make_q_actor(env.observation_spec, env.action_spec, num_cells=[8])
    rollout = env.rollout(5, actor)
    assert rollout["observation"].dtype == torch.float32
    assert rollout["next", "observation"][0, -1].tolist() == [5.0, 5.0, 5.0]


def test_an_env_class_in_the_folder_the_command_runs_from_is_found(tmp_path, monkeypatch):
    """``env.id=my_module:MyEnv`` with ``my_module.py`` where the command runs: no PYTHONPATH
    (``scripts/train.py`` starts ``sys.path`` with its own folder, not the working one)."""
    from trl_cartpole.envs.ids import resolve_env_id

    (tmp_path / "my_corridor_env.py").write_text((ROOT / "examples" / "corridor.py").read_text())
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", ".", str(tmp_path))])
    monkeypatch.delitem(sys.modules, "my_corridor_env", raising=False)
    assert resolve_env_id("my_corridor_env:Corridor") == "my_corridor_env.Corridor"
    assert isinstance(gym.make("my_corridor_env.Corridor").observation_space, gym.spaces.Box)


def test_a_run_of_an_env_class_is_named_without_a_colon(compose):
    """``env.id=my_module:MyEnv`` gives ``runs/my_module-MyEnv-dqn-seed0-<time>``: no ``:``,
    which some shells, tools and file systems take for something else."""
    name = Path(str(compose("env.id=corridor:Corridor").run_dir)).name
    assert name.startswith("corridor-Corridor-dqn-seed0-") and ":" not in name
