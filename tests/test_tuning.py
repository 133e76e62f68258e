"""trl-cartpole tune: an Optuna study that prunes, resumes from SQLite and writes a preset."""

from __future__ import annotations

import shutil

import pytest
import yaml

from trl_cartpole.config.compose import compose_config
from trl_cartpole.errors import ConfigError
from trl_cartpole.tools.tuning import (
    QUIET_RUN,
    curve_score,
    load_search_space,
    objective_overrides,
    variant_switch_defaults,
    write_preset,
)

from .conftest import CONFIG_DIR, run_script, run_script_in_process

optuna = pytest.importorskip("optuna")

# 3 000 frames, evaluations at 1 024, 2 048 and 3 072 frames (20 episodes each).
TINY = ["collector.total_frames=3000", "eval.interval_frames=1000", "eval.final_episodes=5"]


def test_the_score_is_the_mean_of_the_curve_held_at_its_last_value():
    assert curve_score([10.0, 20.0, 30.0], 3) == 20.0
    assert curve_score([10.0, 500.0], 4) == (10 + 500 * 3) / 4  # stopped solved: 500 held
    assert curve_score([], 3) == float("-inf")


def test_the_frames_objective_reports_its_lower_bound_and_holds_a_solve():
    from types import SimpleNamespace

    from trl_cartpole.tools.tuning import OBJECTIVES, frames_score, run_frames_score, seed_reporter

    assert OBJECTIVES == {"return": "maximize", "frames": "minimize", "seconds": "minimize"}
    assert frames_score(12288, 30000) == 12288.0 and frames_score(None, 30000) == 60000.0
    cfg = SimpleNamespace(
        collector=SimpleNamespace(total_frames=5000, frames_per_batch=32),
        eval=SimpleNamespace(interval_frames=1000),  # evaluations at 1 024, 2 048, ... frames
    )

    def solves_at_2048(cfg, on_evaluation):
        for frames, solved in ((1024, False), (2048, True)):
            on_evaluation(SimpleNamespace(frames=frames, solved=solved))
        return {"frames_to_solve": 2048}

    reports = []
    assert run_frames_score(solves_at_2048, cfg, lambda *step: reports.append(step)) == 2048.0
    # its frames so far, then the solve held at the steps the budget would still evaluate
    assert reports == [(1024, 1024.0), (2048, 2048.0), (3072, 2048.0), (4096, 2048.0)]
    # the second seed's steps follow the first's budget; its value is the mean with seed 0's
    seen = []
    seed_reporter(lambda *step: seen.append(step), 5000, [3000.0])(1024, 1024.0)
    assert seen == [(6024, 2012.0)]


def test_the_seconds_objective_reports_training_seconds_and_holds_a_solve():
    from types import SimpleNamespace

    from trl_cartpole.tools.tuning import run_seconds_score, seconds_score

    assert seconds_score(7.5, 30.0) == 7.5 and seconds_score(None, 30.0) == 60.0
    cfg = SimpleNamespace(
        collector=SimpleNamespace(total_frames=4000, frames_per_batch=32),
        eval=SimpleNamespace(interval_frames=1000),
    )

    def solves_at_2048(cfg, on_evaluation):
        for frames, seconds, solved in ((1024, 1.5, False), (2048, 3.25, True)):
            on_evaluation(SimpleNamespace(frames=frames, seconds=seconds, solved=solved))
        return {"seconds_to_solve": 3.25, "train_seconds": 3.3}

    def never_solves(cfg, on_evaluation):
        on_evaluation(SimpleNamespace(frames=1024, seconds=1.5, solved=False))
        return {"seconds_to_solve": None, "train_seconds": 4.0}

    reports = []
    assert run_seconds_score(solves_at_2048, cfg, lambda *step: reports.append(step)) == 3.25
    assert reports == [(1024, 1.5), (2048, 3.25), (3072, 3.25)]  # held at 3 072 (< 4 000 + 32)
    assert run_seconds_score(never_solves, cfg, lambda *step: None) == 8.0


def test_an_unknown_objective_or_a_study_of_the_other_direction_is_refused(tmp_path):
    out = f"out={tmp_path / 'x.yaml'}"
    proc = run_script_in_process("tune.py", "trials=1", out, "objective=wins")
    assert proc.returncode == 2 and proc.stderr.splitlines() == [
        "error: objective='wins'; choose one of return, frames, seconds"
    ]
    from trl_cartpole.tools.study import run_study

    storage = f"sqlite:///{tmp_path / 'study.db'}"
    optuna.create_study(study_name="s", storage=storage, direction="maximize")
    with pytest.raises(ConfigError, match=r"made to maximize .* objective=frames needs one"):
        run_study(
            CONFIG_DIR,
            [],
            1,
            tmp_path / "x.yaml",
            storage=storage,
            study_name="s",
            objective="frames",
        )
    assert not (tmp_path / "x.yaml").exists()


def test_a_search_space_is_checked_and_lists_pass_as_written(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("optim.lr: {low: 0.1}\n")
    with pytest.raises(ConfigError, match=r"optim\.lr: .* is neither"):
        load_search_space(bad)
    overrides = objective_overrides({"network.num_cells": "[64, 64]", "loss.double_dqn": True})
    assert overrides == ["network.num_cells=[64, 64]", "loss.double_dqn=true"]
    space = load_search_space(CONFIG_DIR / "tune" / "cartpole.yaml")
    cfg = compose_config(
        CONFIG_DIR, [f"{k}={v['choices'][0]}" for k, v in space.items() if "choices" in v]
    )  # every choice is a valid override
    assert cfg.network.num_cells == [64, 64]


@pytest.mark.slow  # an Optuna study of training runs
def test_a_tiny_study_prunes_resumes_and_writes_a_preset_that_trains(tmp_path, monkeypatch):
    from trl_cartpole.run.training import train
    from trl_cartpole.tools.study import run_study

    monkeypatch.chdir(tmp_path)  # the study's directory: runs/tune/<study>
    configs = tmp_path / "configs"
    shutil.copytree(CONFIG_DIR, configs)
    space = tmp_path / "space.yaml"
    space.write_text("optim.lr: {low: 1.0e-7, high: 1.0e-2, log: true}\n")
    storage = f"sqlite:///{tmp_path / 'study' / 'study.db'}"
    (tmp_path / "study").mkdir()
    study = optuna.create_study(study_name="tiny", storage=storage, direction="maximize")
    # Evaluations at 1 024 and 2 048 frames and at the run's end (3 008).
    study.enqueue_trial({"optim.lr": 4e-3})
    study.enqueue_trial({"optim.lr": 1e-7})  # learns nothing: pruned by construction
    # After 1 500 frames (the second evaluation on), a running score below 20 is pruned.
    pruner = optuna.pruners.ThresholdPruner(lower=20.0, n_warmup_steps=1500)
    out = configs / "env" / "tiny_tuned.yaml"
    options = dict(
        config_dir=configs,
        overrides=TINY,
        out=out,
        storage=storage,
        study_name="tiny",
        space_path=space,
        pruner=pruner,
    )
    first = run_study(trials=2, **options)
    assert (first.finished, first.pruned) == (2, 1)
    assert first.best_params == {"optim.lr": 4e-3}
    # The score is the mean of the trial's evaluation curve: the same run, made again here
    # (a run repeats itself on one machine; its values depend on the CPU's float kernels).
    again = train(
        compose_config(
            configs,
            [*TINY, "optim.lr=0.004", "seed=0", f"run_dir={tmp_path / 'again'}", *QUIET_RUN],
        )
    )
    returns = again["eval_curve"]["returns"]
    assert len(returns) == 3 and first.best_value == pytest.approx(sum(returns) / 3, abs=1e-9)
    # The same storage and more trials: the study continues (a third trial, TPE-sampled).
    second = run_study(trials=3, **options)
    assert (
        second.finished == 3
        and len(optuna.load_study(study_name="tiny", storage=storage).trials) == 3
    )
    assert (tmp_path / "study" / "history.png").is_file()
    # The preset is a train.py preset by name: its tuned lr and the base preset's env.
    text = out.read_text()
    assert text.startswith("# @package _global_\n# CartPole-v1 tuned by trl-cartpole tune")
    cfg = compose_config(
        configs,
        [
            "env=tiny_tuned",
            *TINY,
            f"run_dir={tmp_path / 'run'}",
            "logger.plots=false",
            "logger.progress_bar=false",
        ],
    )
    assert cfg.optim.lr == second.best_params["optim.lr"] and cfg.env.id == "CartPole-v1"
    assert train(cfg)["frames"] > 0


def test_tune_answers_help_and_refuses_a_missing_space(tmp_path):
    proc = run_script("tune.py", "--help", timeout=60)
    assert proc.returncode == 0 and "trials=" in proc.stdout and "storage=" in proc.stdout
    proc = run_script(
        "tune.py",
        "trials=1",
        f"out={tmp_path / 'x.yaml'}",
        f"space={tmp_path / 'none.yaml'}",
        f"storage=sqlite:///{tmp_path / 'db' / 'study.db'}",
    )
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(errors) == 1 and "does not exist" in errors[0]


@pytest.mark.parametrize(
    "space", sorted((CONFIG_DIR / "tune").glob("*.yaml")), ids=lambda p: p.stem
)
def test_every_search_space_samples_a_valid_config_of_its_env_preset(space):
    from trl_cartpole.config.schema import to_config
    from trl_cartpole.config.validation import validate
    from trl_cartpole.tools.tuning import suggest

    trial = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0)).ask()
    params = suggest(trial, load_search_space(space))
    cfg = compose_config(CONFIG_DIR, [f"env={space.stem}", *objective_overrides(params)])
    validate(to_config(cfg))  # raises on an impossible value
    assert cfg.optim.lr == params["optim.lr"]


def test_a_tuned_preset_leaves_out_a_variant_switch_at_its_default(tmp_path):
    # env presets apply after algo presets: a tuned preset that wrote double_dqn: false would
    # turn algo=double back into plain DQN
    configs = tmp_path / "configs"
    shutil.copytree(CONFIG_DIR, configs)
    switches = variant_switch_defaults(configs)
    assert switches["loss.double_dqn"] is False and switches["network.head"] == "plain"
    assert "optim.lr" not in switches and "loss.gamma" not in switches  # recipe, not variant
    base = {"env": {"id": "Acrobot-v1"}, "buffer": {"n_steps": 5}, "loss": {"gamma": 0.99}}
    params = {"buffer.n_steps": 3, "loss.double_dqn": False, "optim.lr": 1e-3}
    out = configs / "env" / "tuned.yaml"
    write_preset(out, base, params, ["Acrobot-v1 tuned"], switches)
    written = yaml.safe_load(out.read_text())
    # n_steps 3 is the default: dropped with the base's 5, and the section it leaves empty
    assert written == {"env": {"id": "Acrobot-v1"}, "loss": {"gamma": 0.99}, "optim": {"lr": 1e-3}}
    double = compose_config(configs, ["env=tuned", "algo=double"])
    assert double.loss.double_dqn is True and double.buffer.n_steps == 3
    assert double.optim.lr == 1e-3 and double.loss.gamma == 0.99
    # a switch tuned away from its default is the preset's own choice: written
    write_preset(out, base, {"loss.double_dqn": True}, ["tuned"], switches)
    assert yaml.safe_load(out.read_text())["loss"] == {"gamma": 0.99, "double_dqn": True}
