"""The benchmark harness and the ``python -m benchmarks`` subcommands."""

from __future__ import annotations

import json
import math
import os
import subprocess
import threading
import time
from itertools import chain

import pytest

from benchmarks import harness
from benchmarks.ablate import BEGIN, plot_seed_groups, write_between_markers
from benchmarks.envs import table as env_table
from benchmarks.harness import speed_ratios
from benchmarks.profile import phase_table
from benchmarks.run import iqm_ratio_lines, ratio_lines
from benchmarks.update_cost import COMPILED, FLOOR, RAW, update_flops
from benchmarks.wall import wall_table
from trl_cartpole.config.schema import to_config

from .conftest import ROOT, summary_of


def test_env_table_needs_every_seed_at_the_target_and_lunarlanders_median():
    def runs(finals, curve_returns=(-500.0, -90.0, -78.0)):  # evaluations at 2, 5 and 9 s
        return [
            {
                "final_eval_return_mean": final,
                "env_id": "Env-v0",
                "frames": 1000,
                "train_seconds": 10.0,
                "wall_seconds": 12.0,
                "eval_curve": {"seconds": [2.0, 5.0, 9.0], "returns": list(curve_returns)},
            }
            for final in finals
        ]

    text = env_table(
        {
            "acrobot": runs([-70.0, -75.0, -79.0, -81.0, -72.0]),  # one seed below -80
            "mountaincar": runs([-100.0, -104.0, -99.0, -101.0, -102.0]),
            "lunarlander": runs([230.0, 210.0, 250.0, 260.0, 235.0]),  # median 235 < 240
        }
    ).splitlines()
    acrobot, mountaincar, lunarlander = (row.split(" | ") for row in text[2:])
    # IQM of 5 scores: floor(5 / 4) = 1 cut at each end, the mean of the middle 3
    assert acrobot[3].startswith(f"{(-79 - 75 - 72) / 3:.1f} [") and "(5 seeds)" in acrobot[3]
    assert acrobot[4:6] == ["-75.0", "-81.0"]  # median, worst seed
    assert acrobot[7] == "no (4/5 seeds)"
    assert mountaincar[7] == "yes (5/5 seeds)"
    assert lunarlander[2] == "every seed >= 200, median >= 240"
    assert lunarlander[7] == "no (5/5 seeds)"
    # training seconds to the first evaluation at or above the target: -80 (Acrobot) at 9 s,
    # -105 (MountainCar) at 5 s, 200 (LunarLander) never
    assert [acrobot[9], mountaincar[9], lunarlander[9]] == ["9", "5", "never"]
    reached_at = {9.0: (-500.0, -90.0, -78.0), 5.0: (-500.0, -79.0, -90.0), None: (-99.0,) * 3}
    seeds = [runs([-70.0], reached_at[at])[0] for at in (9.0, 5.0, None, None, None)]
    median_of = [env_table({"acrobot": seeds[:n]}).splitlines()[2].split(" | ")[9] for n in (3, 5)]
    assert median_of == ["9", "never"]  # 5, 9, never: 9; 5, 9, never x3: never (slowest)


def test_speed_ratios_divide_medians_and_name_the_unsolved():
    results = {
        "ours": [
            summary_of(1000, 2.0, 500.0),
            summary_of(2000, 4.0, 500.0),
            summary_of(None, None, 9),
        ],
        "peer": [
            summary_of(9000, 30.0, 500.0),
            summary_of(9000, 10.0, 500.0),
            summary_of(1, 20.0, 1),
        ],
        "stuck": [summary_of(None, None, 9.0)] * 3,
    }
    ratios = speed_ratios(results, "ours", ["peer", "stuck"])
    assert ratios["peer"] == 20.0 / 4.0  # medians: 20 s vs 4 s (unsolved counts as slowest)
    assert math.isinf(ratios["stuck"])
    assert speed_ratios(results, "stuck", ["peer", "stuck"]) == {"peer": 0.0, "stuck": None}
    assert ratio_lines(results, ["ours"], ["peer", "stuck"])[:2] == [
        "- peer needs 5.0x the seconds to solve of ours (medians)",
        "- stuck solved 0 of 3 seeds: no median to compare",  # not "infx"
    ]


def test_iqm_ratios_carry_their_intervals_and_say_whether_they_are_apart():
    ours = [summary_of(1000, float(s), 500.0) for s in (1, 2, 3, 4)]
    peer = [summary_of(9000, float(s), 500.0) for s in (10, 20, 30, 40)]
    close = [summary_of(9000, float(s), 500.0) for s in (2, 3, 4, 5)]
    stuck = [summary_of(None, None, 9.0)] * 4
    results = {"ours": ours, "peer": peer, "close": close, "stuck": stuck}
    lines = iqm_ratio_lines(results, "ours", ["peer", "close", "stuck"])
    # IQM of 4 seeds: the middle two; (20 + 30) / 2 over (2 + 3) / 2 = 10
    assert lines[0].startswith("- IQM seconds to solve: peer 25.0 [")
    assert "against ours 2.5 [" in lines[0]
    assert lines[0].endswith(": 10.0x, intervals apart")
    assert lines[1].endswith(": 1.4x, intervals overlap")  # 3.5 / 2.5
    assert lines[2].endswith("stuck left more than a quarter of its seeds unsolved")


def test_seed_group_plot_and_doc_markers(tmp_path):
    curves = {"x": [([1000, 2000], [10.0, 480.0]), ([1000, 2000, 3000], [9.0, 100.0, 490.0])]}
    image = plot_seed_groups(curves, tmp_path / "plot.png", threshold=475)
    assert image.stat().st_size > 1000
    doc = tmp_path / "doc.md"
    doc.write_text("# Title\n\nprose\n")
    write_between_markers(doc, "table 1")
    write_between_markers(doc, "table 2")  # replaces, keeps the prose
    text = doc.read_text()
    assert text.startswith("# Title\n\nprose\n") and text.count(BEGIN) == 1
    assert "table 2" in text and "table 1" not in text


def _benchmarks(python, *args, **kwargs) -> subprocess.CompletedProcess:
    """``python -m benchmarks ARGS`` from the repository root."""
    return subprocess.run(
        [python, "-m", "benchmarks", *args], capture_output=True, text=True, cwd=ROOT, **kwargs
    )


@pytest.mark.slow  # one subprocess per benchmark subcommand
def test_every_subcommand_shows_help_with_the_shared_arguments(python):
    proc = _benchmarks(python, "--help")
    assert proc.returncode == 0, proc.stderr
    subcommands = ["run", "ablate", "envs", "scaling", "update-cost", "profile", "wall", "memory"]
    assert all(name in proc.stdout for name in subcommands)
    for name in subcommands:
        proc = _benchmarks(python, name, "--help")
        assert proc.returncode == 0, proc.stderr
        assert all(arg in proc.stdout for arg in ("--seeds", "--jobs", "--out", "overrides"))


def test_phase_table_gives_medians_over_seeds_and_shares_of_training_time():
    summaries = [
        {
            "train_seconds": 10.0,
            "wall_seconds": 13.0,
            "phase_seconds": {"collect": 2.0, "update": 6.0},
        },
        {
            "train_seconds": 20.0,
            "wall_seconds": 22.0,
            "phase_seconds": {"collect": 4.0, "update": 15.0},
        },
        {
            "train_seconds": 12.0,
            "wall_seconds": 16.0,
            "phase_seconds": {"collect": 3.0, "update": 8.0},
        },
    ]
    # medians: train 12, collect 3 (25 %), update 8 (66.7 %); not in a phase: 2, 1, 1 -> 1
    # (8.3 %); outside training: 3, 2, 4 -> 3
    assert phase_table(summaries).splitlines()[2:] == [
        "| collect | 3.00 | 25.0 % |",
        "| update | 8.00 | 66.7 % |",
        "| not in a phase | 1.00 | 8.3 % |",
        "| **training** | 12.00 | 100 % |",
        "| evaluation, checkpoints, start-up (not training) | 3.00 | - |",
    ]


def test_wall_table_splits_the_wall_time_and_gives_the_median_ratio():
    # import, wall, training, rest, start-up and exit, ratio = wall / (training + import)
    rows = {0: (4.0, 20.0, 12.0, 3.0, 5.0, 20.0 / 16.0), 1: (4.0, 23.0, 16.0, 4.0, 3.0, 1.15)}
    lines = wall_table(rows).splitlines()
    assert lines[2] == "| 0 | 4.00 | 20.00 | 12.00 | 3.00 | 5.00 | 1.25 |"
    assert lines[4] == "| median | 4.00 | 21.50 | 14.00 | 3.50 | 4.00 | 1.20 |"
    assert lines[-1] == "median ratio 1.20 (target <= 1.25: met)"
    slow = {0: (4.0, 30.0, 12.0, 3.0, 15.0, 30.0 / 16.0)}
    assert wall_table(slow).endswith("median ratio 1.88 (target <= 1.25: not met)")


@pytest.mark.slow  # times updates of every preset, and compiles one
def test_update_cost_prints_a_row_per_preset_and_records_the_compiled_and_raw_rows(
    python, tmp_path
):
    record = tmp_path / "update_cost.json"
    proc = _benchmarks(
        python,
        "update-cost",
        "--algos",
        "dqn",
        "rainbow",
        "--updates",
        "3",
        "--out",
        str(tmp_path),
        "--record",
        str(record),
        "num_threads=0",  # every core this process may use, as training reads it
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    totals = {
        line.split("|")[1].strip(): float(line.split("|")[-2])
        for line in proc.stdout.splitlines()
        if line.startswith("| ") and not line.startswith("| update") and "---" not in line
    }
    assert {"dqn", "rainbow", COMPILED, RAW, FLOOR} == set(totals)
    assert all(total > 0 for total in totals.values())
    assert "framework tax (dqn / raw): " in proc.stdout
    (run,) = json.loads(record.read_text())["runs"]
    assert [row["name"] for row in run["rows"]] == ["dqn", COMPILED, RAW, FLOOR]
    assert run["compile_seconds"] > 0 and run["overrides"] == ["num_threads=0"]
    assert run["num_threads"] == len(os.sched_getaffinity(0))


@pytest.mark.parametrize("double", [False, True])
def test_the_flop_floor_counts_the_matrix_products_an_update_runs(compose, double):
    # torch's own FLOP counter over one eager update of the built learner (its products and
    # convolutions only, as the floor): the formula counts the same operations
    from torch.utils.flop_counter import FlopCounterMode

    from trl_cartpole.parts.replay import extend_with_batch
    from trl_cartpole.run.from_config import (
        build_actor,
        build_env,
        build_learner,
        build_replay_buffer,
        transition_keys,
    )

    # fast=true: the same arithmetic on plain tensors (torch's module tracker cannot key a
    # TensorDictModule, so it does not count through the stock DQNLoss)
    overrides = ("fast=true", "buffer.batch_size=64", f"loss.double_dqn={str(double).lower()}")
    cfg = to_config(compose(*overrides))
    env = build_env(cfg, 0)
    actor = build_actor(cfg, env)
    learner = build_learner(cfg, actor, build_replay_buffer(cfg))
    rollout = env.rollout(10, break_when_any_done=False)  # [envs, 10]
    extend_with_batch(learner.buffer, rollout.select(*transition_keys(actor.in_keys[0])))
    env.close()
    sample = learner.buffer.sample()
    with FlopCounterMode(display=False) as counter:
        learner.update(sample)
    assert counter.get_total_flops() == update_flops(cfg, 4, 2)


@pytest.mark.slow  # fresh interpreters
def test_benchmark_refuses_a_bad_job_count_before_running_anything(python, tmp_path):
    proc = _benchmarks(python, "run", "--jobs", "0", "--out", str(tmp_path))
    assert proc.returncode == 2
    assert "--jobs 0: run at least one process at a time" in proc.stderr
    assert not any(tmp_path.iterdir())  # no run started


def test_a_peer_venv_asked_for_by_two_runs_at_once_is_made_once(tmp_path, monkeypatch):
    """``--jobs 2`` starts two runs of a peer at the same moment: before the lock, both removed
    and re-made its virtual environment, each under the other's pip install."""
    made = []

    def slow_make(peer, venv):  # stands in for venv + pip: slow enough for the threads to meet
        made.append(peer)
        time.sleep(0.2)
        venv.mkdir(parents=True, exist_ok=True)
        (venv / ".complete").write_text(" ".join(harness._venv_packages(peer)) + "\n")

    monkeypatch.setattr(harness, "REPOSITORY", tmp_path)
    monkeypatch.setattr(harness, "_make_peer_venv", slow_make)
    pythons = []
    threads = [
        threading.Thread(target=lambda: pythons.append(harness.peer_python("tianshou_dqn")))
        for _ in range(2)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert made == ["tianshou_dqn"]
    expected = tmp_path / "runs" / "peer-venvs" / "tianshou_dqn" / "bin" / "python"
    assert pythons == [str(expected), str(expected)]
    assert harness.peer_python("sb3_dqn") == harness.sys.executable  # no venv of its own
    monkeypatch.setitem(harness.PEER_VENVS, "tianshou_dqn", ["tianshou==2.0.2"])
    harness.peer_python("tianshou_dqn")  # other pins: made again
    assert made == ["tianshou_dqn", "tianshou_dqn"]


def test_a_preset_with_overrides_of_its_own_runs_them_after_the_shared_ones(tmp_path, monkeypatch):
    from hydra.core.override_parser.overrides_parser import OverridesParser

    commands = {}
    monkeypatch.setattr(
        harness, "_run_once", lambda command, run_dir: commands.setdefault(run_dir.name, command)
    )
    algos = ["dqn", "dqn+fast=true+env.id=my_module:MyEnv"]
    results = harness.run_presets(algos, [7], tmp_path, ["buffer.batch_size=64"])
    assert list(results) == algos
    plain, own = commands["dqn-seed7"], commands["dqn_fast_true_env.id_my_module_MyEnv-seed7"]
    assert plain[2:4] == own[2:4] == ["algo=dqn", "seed=7"]
    assert plain[-1] == "buffer.batch_size=64"
    assert own[-3:] == ["buffer.batch_size=64", "fast=true", "env.id=my_module:MyEnv"]
    parsed = OverridesParser.create().parse_overrides(own[2:])  # as scripts/train.py reads them
    assert {o.key_or_group: o.value() for o in parsed}["fast"] is True


def test_the_memory_row_subtracts_what_the_buffer_filled(tmp_path):
    from benchmarks.memory import memory_row

    (tmp_path / "config.yaml").write_text("buffer:\n  size: 1000\n")
    component = tmp_path / "checkpoints" / "last" / "components" / "0004-replay_buffer"
    component.mkdir(parents=True)
    (component / "storage.memmap").write_bytes(b"\0" * 2**20)  # a 1 MiB buffer
    summary = {
        "seed": 7,
        "peak_rss_mb": 210.0,
        # the first evaluation had no reading (a state from before it): skipped
        "eval_curve": {"frames": [50, 100, 500, 2000], "rss_mb": [None, 200.0, 200.5, 201.0]},
    }
    # filled between frames 100 and 2000: 1 MiB * (1000 - 100) / 1000 = 0.9 MiB;
    # growth beyond it: 201 - 200 - 0.9 = +0.1 MiB
    assert memory_row(tmp_path, summary) == [
        "7",
        "3",
        "200 (100)",
        "201 (2000)",
        "210",
        "1.0",
        "0.9",
        "+0.1",
    ]


def test_an_atari_record_keeps_the_seeds_measured_before_and_replaces_one_measured_again(
    tmp_path,
):
    from benchmarks.atari import _merged_record

    path = tmp_path / "atari.json"
    before = {"date": "2026-11-27", "commit": "a" * 40, "machine": {"cpu": "old", "cores": 2}}
    first = _merged_record(
        path, [{"seed": 104, "score": 1}, {"seed": 103, "score": 2}], "c1", before
    )
    assert [run["seed"] for run in first["runs"]] == [103, 104]
    path.write_text(json.dumps(first))
    now = {"date": "2026-11-28", "commit": "b" * 40, "machine": {"cpu": "new", "cores": 2}}
    second = _merged_record(path, [{"seed": 104, "score": 3}, {"seed": 105, "score": 4}], "c2", now)
    assert [(run["seed"], run["score"]) for run in second["runs"]] == [(103, 2), (104, 3), (105, 4)]
    assert [run["measured"]["date"] for run in second["runs"]] == [
        "2026-11-27",
        "2026-11-28",
        "2026-11-28",
    ]
    assert second["date"] == "2026-11-28" and second["command"] == "c1\nc2"
    # a file written before runs carried their own provenance lends them its own
    path.write_text(json.dumps({**before, "command": "c0", "runs": [{"seed": 101}]}))
    third = _merged_record(path, [{"seed": 102}], "c0", now)
    assert third["runs"][0]["measured"]["machine"]["cpu"] == "old"
    assert third["command"] == "c0"
    # two games of one seed are two runs: measuring one again leaves the other
    path.write_text(json.dumps(third))
    games = [{"seed": 300, "env_id": "ALE/Breakout-v5"}, {"seed": 300, "env_id": "ALE/Boxing-v5"}]
    both = _merged_record(path, games, "c3", now)
    path.write_text(json.dumps(both))
    again = _merged_record(path, [{"seed": 300, "env_id": "ALE/Boxing-v5", "score": 6}], "c3", now)
    assert [(run["seed"], run.get("env_id"), run.get("score")) for run in again["runs"]] == [
        (101, None, None),
        (102, None, None),
        (300, "ALE/Boxing-v5", 6),
        (300, "ALE/Breakout-v5", None),
    ]
    # a run recorded before runs named their game is replaced by its seed measured again
    gameless = _merged_record(path, [{"seed": 101, "env_id": "ALE/Breakout-v5"}], "c0", now)
    assert [(run["seed"], run.get("env_id")) for run in gameless["runs"]][:2] == [
        (101, "ALE/Breakout-v5"),
        (102, None),
    ]


def test_provenance_says_which_kernels_torch_runs_and_the_limits_set(monkeypatch):
    import torch

    for name in ("ONEDNN_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY", "MKL_ENABLE_INSTRUCTIONS"):
        monkeypatch.delenv(name, raising=False)
    kernels = harness.provenance()["machine"]["kernels"]
    assert kernels["torch"] == torch.backends.cpu.get_cpu_capability()
    assert isinstance(kernels["computes_bfloat16"], bool) and "limits" not in kernels
    monkeypatch.setenv("MKL_ENABLE_INSTRUCTIONS", "AVX2")
    assert harness.provenance()["machine"]["kernels"]["limits"] == {
        "MKL_ENABLE_INSTRUCTIONS": "AVX2"
    }


@pytest.mark.slow  # two pixel learners on 3 000 random frames each
def test_channels_last_kernels_give_the_same_q_values_and_update():
    """The update-cost's channels-last row changes the memory format of the convolution
    kernels, online and target, not what the update computes nor what the target copies."""
    import torch

    from benchmarks import update_cost

    overrides = ["env=cartpole_pixels", "collector.updates_per_batch=1"]
    _, plain, _ = update_cost._built("dqn", 0, overrides)
    _, nhwc, _ = update_cost._built("dqn", 0, overrides)
    assert update_cost.to_channels_last(nhwc) == 6  # 3 convolutions, online and target
    kernels = [t for t in chain(nhwc.loss.parameters(), nhwc.loss.buffers()) if t.dim() == 4]
    assert len(kernels) == 6
    assert all(t.is_contiguous(memory_format=torch.channels_last) for t in kernels)
    sample = plain.buffer.sample()
    for _ in range(2):  # an update, the target's copy, an update from the copied target
        plain.update(sample.clone())
        nhwc.update(sample.clone())
        plain.target_updater.init_()  # the online weights copied into the target's
        nhwc.target_updater.init_()
    plain_state = [*plain.loss.parameters(), *plain.loss.buffers()]
    nhwc_state = [*nhwc.loss.parameters(), *nhwc.loss.buffers()]
    for a, b in zip(plain_state, nhwc_state, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
    assert all(t.is_contiguous(memory_format=torch.channels_last) for t in kernels)
    online, target = kernels[:3], kernels[3:]  # the copy reached the channels-last target
    assert all(torch.equal(a, b) for a, b in zip(online, target, strict=True))


def test_an_update_cost_held_to_avx2_is_kept_beside_the_native_one(tmp_path, monkeypatch):
    import argparse

    from benchmarks import update_cost

    record = tmp_path / "update_cost.json"
    args = argparse.Namespace(seeds=[0], updates=3, overrides=["env=breakout"], note="")
    args.record = record
    for name in ("ONEDNN_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY", "MKL_ENABLE_INSTRUCTIONS"):
        monkeypatch.delenv(name, raising=False)
    update_cost._record(args, {"rows": [], "first": True})
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
    update_cost._record(args, {"rows": [], "first": False})
    update_cost._record(args, {"rows": [], "again": True})  # the same kind: replaced
    runs = json.loads(record.read_text())["runs"]
    assert len(runs) == 2 and "first" not in runs[1]
    assert runs[0]["first"] and runs[1]["again"]
    assert runs[1]["machine"]["kernels"]["limits"] == {"ONEDNN_MAX_CPU_ISA": "AVX2"}


def test_two_pinned_peer_runs_at_once_get_a_core_each(tmp_path, monkeypatch):
    """XLA spreads over every core, so the harness pins an SBX run to a core no other pinned
    run holds, and gives it back when the run ends."""
    import queue

    cores = queue.Queue()
    for core in (3, 7):
        cores.put(core)
    held = []

    def run_once(command, run_dir, core=None):
        held.append(core)
        time.sleep(0.2)  # both runs at once
        return {"core": core}

    monkeypatch.setattr(harness, "_FREE_CORES", cores)
    monkeypatch.setattr(harness, "_run_once", run_once)
    monkeypatch.setattr(harness, "peer_python", lambda peer: harness.sys.executable)
    threads = [
        threading.Thread(target=harness.run_peer, args=("sbx_dqn", seed, tmp_path))
        for seed in (0, 1)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(held) == [3, 7]
    assert sorted([cores.get_nowait(), cores.get_nowait()]) == [3, 7]  # given back
    harness.run_peer("sb3_dqn", 0, tmp_path)  # torch's one thread: not pinned
    assert held[-1] is None


def test_a_preset_spec_with_an_empty_piece_or_a_shared_folder_is_refused(tmp_path):
    with pytest.raises(SystemExit, match=r"--algos 'dqn\+\+a=1': write a preset"):
        harness.run_training("dqn++a=1", 0, tmp_path)
    with pytest.raises(SystemExit, match="two entries would share a run folder"):
        harness.run_presets(["dqn+a=1", "dqn+a_1"], [0], tmp_path)
