"""Config composition, the presets, and bad input stopping the run with one clear line."""

from __future__ import annotations

import json
import subprocess

import pytest
from hydra.errors import HydraException
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from trl_cartpole.config.compose import compose_config
from trl_cartpole.config.presets import PRESETS_DIR
from trl_cartpole.config.schema import Config, to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.errors import ConfigError
from trl_cartpole.store.checkpoint import save_policy

from .conftest import SCRIPTS


def test_default_config_composes_and_validates(compose):
    cfg = validate(to_config(compose()))
    assert isinstance(cfg, Config)
    assert cfg.env.id == "CartPole-v1"
    assert cfg.algo.name == "dqn"


def test_schema_defaults_are_the_default_preset(compose):
    """``train({...})`` without Hydra gets the same hyperparameters as ``scripts/train.py``."""
    from_hydra = to_config(compose("run_dir=x"))
    from_schema = to_config({"run_dir": "x"})
    assert from_hydra == from_schema


def test_tutorial_preset_is_the_pytorch_tutorial(compose):
    cfg = validate(to_config(compose("algo=tutorial")))
    assert cfg.algo.name == "tutorial"
    assert cfg.buffer.batch_size == 128 and cfg.buffer.max_size == 10_000
    assert cfg.loss.gamma == 0.99 and cfg.loss.loss_function == "smooth_l1"
    assert cfg.target_updater.kind == "soft" and cfg.target_updater.tau == 0.005
    assert cfg.exploration.schedule == "exponential"
    assert (cfg.exploration.eps_init, cfg.exploration.eps_end) == (0.9, 0.05)
    assert cfg.exploration.annealing_num_steps == 1000
    assert cfg.optim.lr == 1e-4 and cfg.optim.amsgrad and cfg.optim.weight_decay == 0.01
    assert cfg.optim.grad_clip == "value" and cfg.optim.max_grad == 100.0
    assert list(cfg.network.num_cells) == [128, 128]
    assert cfg.collector.frames_per_batch == 1 and cfg.collector.updates_per_batch == 1
    assert cfg.env.num_envs == 1 and cfg.buffer.n_steps == 1  # the tutorial's single-env loop


def test_contract_overrides_apply(compose):
    cfg = to_config(
        compose("seed=3", "run_dir=/tmp/x", "env.id=Acrobot-v1", "collector.total_frames=1234")
    )
    assert (cfg.seed, cfg.run_dir, cfg.env.id) == (3, "/tmp/x", "Acrobot-v1")
    assert cfg.collector.total_frames == 1234


def test_default_run_dir_names_env_algo_and_seed(compose):
    cfg = to_config(compose("seed=5"))
    assert cfg.run_dir.startswith("runs/CartPole-v1-dqn-seed5-")


@pytest.mark.parametrize(
    "override", ["buffer.batchsize=64", "loss.gamma=abc", "env=nosuchpreset", "algo=nosuch"]
)
def test_misspelt_keys_and_wrong_types_fail_composition(compose, override):
    with pytest.raises((HydraException, OmegaConfBaseException)):
        compose(override)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["loss.gamma=1.5"], r"loss.gamma=1.5 must lie in \(0, 1\]"),
        (["loss.gamma=0"], r"loss.gamma=0.0 must lie in \(0, 1\]"),
        (["buffer.max_size=100", "buffer.batch_size=128"], "larger than buffer.max_size=100"),
        (["env.id=CartPoles-v1"], "is not a registered Gymnasium env"),
        (["exploration.eps_init=0.01"], "eps_end <= eps_init"),
        (["loss.loss_function=l3"], "choose one of"),
        (["network.head=fancy"], "network.head='fancy' is not a known option"),
        (["collector.total_frames=0"], "must be >= collector.frames_per_batch"),
        (["buffer.n_steps=0"], "buffer.n_steps=0 must be >= 1"),
        (["buffer.beta=1.5"], r"buffer.beta=1.5 must lie in \[0, 1\]"),
        (["network.atoms=1"], "network.atoms=1 must be >= 2"),
        (["network.v_min=5", "network.v_max=5"], "must be < network.v_max"),
        (["exploration.schedule=greedy"], "choose one of"),
        (["env.num_envs=0"], "env.num_envs=0 must be >= 1"),
        (["num_threads=-1"], "num_threads=-1 must be >= 1, or 0 for every core"),
        # accepted before, then a NaN TD loss (lr) or a nonsense support (v_min) mid-run
        (["optim.lr=inf"], r"optim.lr=inf must be a finite number"),
        (["network.v_min=-inf"], r"network.v_min=-inf must be a finite number"),
        (["buffer.alpha=nan"], r"buffer.alpha=nan must be a finite number"),
        # found by tests/test_fuzz.py: OmegaConf took any integer for a switch
        (["checkpoint.save_best=512"], r"checkpoint.save_best=512 is not a switch value"),
        (
            ["env.num_envs=3", "collector.frames_per_batch=16"],
            "frames_per_batch=16 must be a multiple of env.num_envs=3",
        ),
    ],
)
def test_impossible_values_raise_config_error(compose, overrides, message):
    with pytest.raises(ConfigError, match=message):
        validate(to_config(compose(*overrides)))


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["network.noisy=true"], "set exploration.schedule=none"),
        (["algo=noisy", "exploration.schedule=linear"], "set exploration.schedule=none"),
        (["exploration.schedule=none"], "no exploration at all"),
        (["network.distributional=true"], "cannot switch it off; set loss.double_dqn=true"),
        (["algo=c51", "loss.double_dqn=false"], "set loss.double_dqn=true"),
        (["algo=rainbow", "loss.loss_function=l2"], "cross-entropy"),
    ],
)
def test_combinations_the_code_cannot_honour_are_refused(compose, overrides, message):
    with pytest.raises(ConfigError, match=message):
        validate(to_config(compose(*overrides)))


def test_compile_without_a_cpp_compiler_is_refused_before_the_run(compose, monkeypatch, tmp_path):
    cfg = to_config(compose("compile=true"))
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-compiler"))
    with pytest.raises(ConfigError, match=r"compile=true needs a C\+\+ compiler .*compile=false"):
        validate(cfg)
    monkeypatch.setenv("CXX", "python3")  # any program on PATH passes: the check is for presence
    assert validate(cfg).compile


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("loss.gama=0.5", "loss.gama is not a setting (did you mean 'loss.gamma'?)"),
        ("loss.gamma=1.5", "loss.gamma=1.5 must lie in (0, 1]"),
        ("env.id=Nope-v0", "env.id='Nope-v0' is not a registered Gymnasium env"),
        ("buffer.batch_size=big", "buffer.batch_size='big' is not an integer"),
        ("network.noisy=true", "set exploration.schedule=none"),
    ],
)
def test_cli_bad_input_is_one_line_and_exit_2(python, tmp_path, override, expected):
    run_dir = tmp_path / "run"
    proc = subprocess.run(
        [python, str(SCRIPTS / "train.py"), override, f"run_dir={run_dir}"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and expected in lines[0]
    assert "Traceback" not in proc.stderr
    assert not run_dir.exists()  # nothing written before training


@pytest.mark.parametrize(
    "overrides",
    [
        [],
        *([f"env={path.stem}"] for path in sorted((PRESETS_DIR / "env").glob("*.yaml"))),
        *([f"algo={path.stem}"] for path in sorted((PRESETS_DIR / "algo").glob("*.yaml"))),
    ],
    ids=lambda overrides: overrides[0] if overrides else "default",
)
def test_the_config_a_checkpoint_stores_is_omegaconfs_tree_of_it(overrides, tmp_path):
    # checkpoints store dataclasses.asdict(cfg), the fast form of OmegaConf's container
    import torch
    from torchrl.checkpoint import Checkpoint

    cfg = to_config(compose_config(PRESETS_DIR, overrides))
    saved = save_policy(tmp_path / "policy", torch.nn.Linear(1, 1), cfg)
    stored = Checkpoint.manifest(saved)["metadata"]["config"]
    expected = OmegaConf.to_container(OmegaConf.structured(cfg), resolve=True)
    # the manifest is written with sorted keys: same keys, values and their types
    assert json.dumps(stored, sort_keys=True) == json.dumps(expected, sort_keys=True)
    assert to_config(stored) == cfg


def test_num_threads_zero_is_every_core_this_process_may_use(monkeypatch):
    """0 reads the process's CPU affinity (what ``taskset`` narrows), not the machine's count;
    a positive count is taken as given."""
    from trl_cartpole.run import build

    monkeypatch.setattr(build.os, "sched_getaffinity", lambda pid: {0, 3, 5}, raising=False)
    monkeypatch.setattr(build.os, "cpu_count", lambda: 8)
    assert build.choose_num_threads(0) == 3
    assert build.choose_num_threads(2) == 2
    monkeypatch.delattr(build.os, "sched_getaffinity")
    assert build.choose_num_threads(0) == 8


def test_the_breakout_preset_uses_every_core(compose):
    """One Atari run takes the whole machine by default (issue: a CNN's update gains from a
    second thread); CartPole's default stays on one thread."""
    assert to_config(compose("env=breakout")).num_threads == 0
    assert to_config(compose()).num_threads == 1
