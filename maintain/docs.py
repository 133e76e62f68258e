"""Regenerate every generated block of the docs from its one source (``--check``: fail if stale).

A generated block sits between ``<!-- generated:NAME -->`` and ``<!-- /generated:NAME -->``;
its text comes from the code, the schema, the presets or a results file that a benchmark
wrote, never from a hand copy:

- ``readme-ending``, ``readme-next-steps`` (README.md): the quick start's printed ending and the
  measured time of each next step, from ``docs/results/readme.json`` (``python -m maintain
  readme`` writes it, with the date, commit and machine);
- ``config-fields`` (docs/reference/config.md): every field of the schema with its type, default
  and meaning, the source ``--help`` prints;
- ``algo-presets`` (docs/guide.md): what each ``configs/algo/`` preset sets, read from the YAML;
- ``train-listing`` (docs/architecture.md): ``train()`` as the code has it;
- ``folder-table``, ``module-table`` (docs/architecture.md): the package's folders in
  pyproject.toml's import layers and every module, each with its docstring's first paragraph;
- ``readme-results`` (README.md): the results table, one row per comparison, from
  ``docs/results/performance.json``, ``race_<env>.json`` and the Breakout records;
- ``performance-tables`` (docs/performance.md): the headline tables against the peers, from
  ``docs/results/performance.json`` (``python -m benchmarks run ... --record`` writes it);
- ``performance-phases``, ``performance-targets`` (docs/performance.md): the phases of the
  default's training time and the CartPole targets met or not, from the same file;
- ``race-<env>`` (docs/results/peers.md): each other env preset against Stable-Baselines3, from
  ``docs/results/race_<env>.json`` (``python -m benchmarks run --env <env> ... --record``);
- ``pixel-seeds`` (docs/environments-measured.md): ``env=cartpole_pixels`` seed by seed, from
  ``docs/results/cartpole_pixels.json`` (``python -m benchmarks envs ... --record``);
- ``lunarlander-in-budget`` (docs/results/peers.md): LunarLander's runs cut at 300 s of training,
  from ``docs/results/lunarlander_300s.json`` (``python -m benchmarks envs ... --record``);
- ``atari-runs`` (docs/results/breakout.md): Breakout seed by seed, a table
  per form of the recipe, from ``docs/results/atari_breakout*.json`` (``python -m benchmarks
  atari --checkpoint RUN_DIR ... --record``);
- ``atari-taper-ablation`` (docs/results/breakout.md): the fourth form trained on the fifth
  form's seeds for as many steps, from ``docs/results/atari_breakout_no_taper.json`` (the
  same command), each seed beside its tapered run;
- ``atari-loop-gap`` (docs/results/breakout.md): the best policies in Gymnasium's loop against
  their runs' own final evaluations, over the tables of ``atari-runs``;
- ``atari-loop-seeds``, ``atari-100k``, ``atari-torchrl-settings``
  (docs/results/breakout.md): best policies over 100 games of Gymnasium's loop, the Atari-100k
  runs beside published means, and TorchRL's example's settings, from
  ``docs/results/atari_loop_seeds.json``, ``atari_100k.json`` and
  ``atari_torchrl_settings.json`` (the same command);
- ``checkpoint-cost`` (docs/reliability.md), ``update-cost`` (docs/results/speed.md): from
  ``docs/results/checkpoint_cost.json`` and ``update_cost.json``;
- ``factory-defaults`` (docs/reference/factories.md): each factory's defaults beside TorchRL's
  and the class it returns, from the signatures (``maintain/reference.py``).

``tests/test_docs_in_sync.py`` runs the check, so CI fails when a doc drifts from its source.
"""

from __future__ import annotations

import argparse
import ast
import inspect
import json
import math
import re
import statistics
import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path

from benchmarks.harness import provenance_line
from benchmarks.run import RACE_ENVS

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "src" / "trl_cartpole"
RESULTS = ROOT / "docs" / "results" / "readme.json"
PERFORMANCE = ROOT / "docs" / "results" / "performance.json"
PIXELS = ROOT / "docs" / "results" / "cartpole_pixels.json"
LUNARLANDER_IN_BUDGET = ROOT / "docs" / "results" / "lunarlander_300s.json"
# The loop reads its time limit after each batch, so a run ends up to one batch past it (a few
# milliseconds for LunarLander's 16 frames and 4 updates): 1 s of slack.
LUNARLANDER_TIME_SLACK_SECONDS = 1.0
# the fifth form's results file (its learning rate tapered): the taper's ablation is read against it
ATARI_TAPERED = ROOT / "docs" / "results" / "atari_breakout_taper.json"
# the sixth form's (the fifth trained on for its whole 2 hours): the form configs/env/breakout.yaml
# sets, whose seeds the README reports
ATARI_WHOLE_2H = ROOT / "docs" / "results" / "atari_breakout_whole_2h.json"
ATARI_PRESET_FORM = ATARI_WHOLE_2H
# the preset on processors without AVX-512 (float32), seeds 311-313
ATARI_AVX2 = ROOT / "docs" / "results" / "atari_breakout_avx2.json"
# the preset trained for 1 hour on a processor with AVX-512 BF16 (the stretch), seeds 411-413
ATARI_STRETCH = ROOT / "docs" / "results" / "atari_breakout_1h_bf16.json"
ATARI_STRETCH_SECONDS = 3600
# Breakout's results files, each a form of the recipe, with the words that name its seeds in the
# README and the line that names it in docs/results/breakout.md
ATARI_RECORDS = (
    (
        ROOT / "docs" / "results" / "atari_breakout.json",
        "the first form's seeds",
        "The first form of the recipe (double DQN, one step per batch), stopped at 50 000 "
        "steps; seeds 101 and 102, side by side",
    ),
    (
        ROOT / "docs" / "results" / "atari_breakout_80k.json",
        "the 80 000-step form's seeds",
        "The second form of the recipe (80 000 steps or 2 hours of training, whichever came "
        "first, batches of 4 steps and 4 updates, plain DQN targets); seeds 103, 104 and 105 "
        "named for it before any ran, each training on one core (103 and 104 side by side for "
        "their first 17 minutes, 104 beside test runs for about 40 minutes of its second hour, "
        "105 on a faster AMD EPYC beside other runs on its second core)",
    ),
    (
        ROOT / "docs" / "results" / "atari_breakout_2h.json",
        "the 2-hour form's seeds",
        "The third form of the recipe (the second trained for its whole 2 hours, one FIRE step "
        "after a reset and a lost life: `env.atari.fire_steps=1` today); seeds 106, 107 and 108 "
        "named for it before any ran, 106 and 107 side by side at commit `be31927`, 108 at "
        "`b98a008` beside seed 109 of the fourth form, each on one core, beside the project's own "
        "tests and checks at times",
    ),
    (
        ROOT / "docs" / "results" / "atari_breakout_bf16.json",
        "the bfloat16 form's seeds",
        "The fourth form of the recipe (the third with its update in bfloat16, "
        "`optim.autocast=bfloat16`, and two FIRE steps); seeds 109, 110 and 111 named for it "
        "before any ran; 109 trained at commit `0f8d46d` beside seed 108 of the third form, "
        "110 and 111 side by side at `b68e802`, each on one core, beside the project's own "
        "tests, a CI run or benchmarks at times",
    ),
    (
        ATARI_TAPERED,
        "the fifth form's seeds",
        "The fifth form of the recipe (the fourth with its learning rate tapered from 1e-4 to "
        "1e-5 over 135 000 steps, `optim.lr_end=1e-5 optim.lr_decay_frames=135000`); seeds 112, "
        "113 and 114 named for it before any ran, each on one core at commit `03c8b46`; 112 and "
        "113 side by side with little else beside them, 114 beside the fourth form's run of seed "
        "112 (below), stopped by Ctrl-C at 78 228 steps and resumed 55 minutes later",
    ),
    (
        ATARI_WHOLE_2H,
        "the sixth form's seeds",
        "The sixth form of the recipe (the fifth trained on for its whole 2 hours, "
        "`collector.total_frames=300000`, the preset); seeds 115, 116 and 117 named for it "
        "before any ran, each on one core; 115 and 116 side by side at commit `b6a96a5`, 117 at "
        "`1d46af7` (the same code) beside the taper's ablation run of seed 113 (below)",
    ),
    (
        ATARI_AVX2,
        "the AVX2 seeds",
        "The sixth form (the preset) on processors without AVX-512, where "
        "`optim.autocast=auto` chose float32 and `num_threads=0` both cores; seeds 311, 312 "
        "and 313 named for it before any ran (commit `d1a2d84`), each on the whole 2-core "
        "machine. 311 at `d1a2d84` on an AMD EPYC with AVX2 and FMA only, beside this "
        "project's tests and two read-only code reviews for about 25 of its minutes; 312 at "
        "`626c967` on an Intel Xeon with AVX-512 BF16 and AMX held to AVX2 "
        "(`ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2`; MKL's matrix products, the dense "
        "layers', were not held), beside this project's short tests, profiling, a peer's "
        "install (at nice 19) and two read-only reviews for about 40 of its minutes; 313 at "
        "`82c9db7` (the same training code) on an Intel Xeon with AVX-512 BF16 and AMX held "
        "to AVX2, MKL included (`MKL_ENABLE_INSTRUCTIONS=AVX2` as well), with only doc edits "
        "beside it",
    ),
    (
        ATARI_STRETCH,
        "the 1-hour seeds",
        "The sixth form (the preset) trained for 1 hour, `collector.max_train_seconds=3600`, on "
        "a processor with AVX-512 BF16, where `optim.autocast=auto` chose bfloat16 and "
        "`num_threads=0` both cores; seeds 411, 412 and 413 named for it before any ran "
        "(commit `73288a3`), each on the whole 2-core machine. 411 at `d35b2df` (the same "
        "training code) on an Intel Xeon with AVX-512 BF16 and AMX, with doc edits, lint and "
        "two short doc tests at nice 19 beside it",
    ),
)
# The taper's ablation: the fourth form (no taper) on the fifth form's seeds, trained to the same
# 200 000 steps
ATARI_NO_TAPER = ROOT / "docs" / "results" / "atari_breakout_no_taper.json"
# Atari-100k (100 000 agent steps, no sticky actions): this project's runs beside the published
# means, DrQ(epsilon) (Agarwal et al. 2021, Dopamine's DrQ_eps) and DER (van Hasselt et al. 2019)
ATARI_100K = ROOT / "docs" / "results" / "atari_100k.json"
ATARI_100K_PUBLISHED = {
    "ALE/Breakout-v5": {"DrQ(epsilon)": 16.1, "DER": 1.9},
    "ALE/Boxing-v5": {"DrQ(epsilon)": 6.0},
    "ALE/Pong-v5": {"DrQ(epsilon)": -8.5},
}
# Kept Breakout policies played 100 games in Gymnasium's loop, the games the loop's 30-game
# column plays (its first 30) against the 70 after them
ATARI_LOOP_SEEDS = ROOT / "docs" / "results" / "atari_loop_seeds.json"
ATARI_LOOP_FIRST_GAMES = 30
# TorchRL's own DQN Atari example's settings on Breakout, given the preset's 2 hours
ATARI_TORCHRL_SETTINGS = ROOT / "docs" / "results" / "atari_torchrl_settings.json"
# the other env presets raced against Stable-Baselines3 (python -m benchmarks run --env ...)
RACES = {env: ROOT / "docs" / "results" / f"race_{env}.json" for env in RACE_ENVS}


def _fenced(text: str, language: str = "") -> str:
    return f"```{language}\n{text.rstrip()}\n```"


def readme_ending() -> str:
    """The ending the quick start's run printed, as ``docs/results/readme.json`` recorded it."""
    results = json.loads(RESULTS.read_text())
    return _fenced(results["quick_start"]["ending"])


def readme_next_steps() -> str:
    """The next-step commands, each with the time it took in the recorded run."""
    results = json.loads(RESULTS.read_text())
    lines = []
    for step in results["next_steps"]:
        seconds = step.get("seconds")
        timing = "" if seconds is None else f" ({_duration(seconds)})"
        lines.append(f"{step['command']:<64} # {step['what']}{timing}")
    machine = results["machine"]
    return (
        _fenced("\n".join(lines), "bash")
        + f"\n\nTimes: command to prompt, one at a time, on an {machine['cpu']} with "
        + f"{machine['cores']} cores ([docs/results/readme.json](docs/results/readme.json) has "
        + "the date, commit and machine of each)."
    )


def _duration(seconds: float) -> str:
    if seconds < 1:
        return "instant"
    if seconds < 90:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min"


def config_fields() -> str:
    """Every leaf field of the schema: key, type, default and meaning (what ``--help`` shows)."""
    from trl_cartpole.config.help import field_help
    from trl_cartpole.config.schema import Config

    rows = ["| field | type | default | meaning |", "| --- | --- | --- | --- |"]
    for key, kind, default, meaning in field_help(Config):
        rows.append(f"| `{key}` | {kind} | `{default}` | {meaning.replace('|', '/')} |")
    return "\n".join(rows)


def algo_presets() -> str:
    """What each ``configs/algo/`` preset sets, from its YAML (comments dropped)."""
    import yaml

    rows = ["| preset | sets |", "| --- | --- |"]
    for path in sorted((PACKAGE / "configs" / "algo").glob("*.yaml")):
        settings = yaml.safe_load(path.read_text()) or {}
        flat = _flatten({k: v for k, v in settings.items() if k != "defaults"})
        shown = ", ".join(f"`{key}={_yaml_value(value)}`" for key, value in flat.items())
        rows.append(f"| `algo={path.stem}` | {shown or 'the schema defaults'} |")
    return "\n".join(rows)


def _flatten(tree: dict, prefix: str = "") -> dict:
    flat = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _yaml_value(value: object) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list):
        return "[" + ",".join(_yaml_value(v) for v in value) + "]"
    return str(value)


def performance_tables(path: Path = PERFORMANCE) -> str:
    """The headline tables of docs/performance.md: per evaluation interval, every preset and
    peer over the seeds, with the ratios, from ``docs/results/performance.json`` (``python -m
    benchmarks run ... --record docs/results/performance.json`` writes it), or another env's
    race from its own results file (``path``)."""
    from benchmarks.harness import PEERS
    from benchmarks.run import protocol_text

    record = json.loads(path.read_text())
    parts = [_fenced(record["command"], "bash"), provenance_line(record)]
    for interval, results in record["protocols"].items():
        names = list(results)
        algos = [name for name in names if name not in PEERS]
        peers = [name for name in names if name in PEERS]
        seeds = len(results[names[0]])
        every = f"{int(interval):,}".replace(",", " ")  # 1 000, as the docs write numbers
        parts.append(f"#### Evaluation every {every} frames, {seeds} seeds")
        parts.append(protocol_text(results, algos, peers))
    return "\n\n".join(parts)


def performance_phases() -> str:
    """docs/performance.md's table of where the default's training time goes: the phases of
    the 20-seed run's first protocol (``benchmarks.profile.phase_table``, from the summaries in
    ``docs/results/performance.json``), with the cost per update and per frame."""
    from benchmarks.profile import phase_table

    record = json.loads(PERFORMANCE.read_text())
    interval, results = next(iter(record["protocols"].items()))
    runs = results["dqn"]

    def per(phase: str, count: str) -> float:  # ms of a phase per update or per frame
        return statistics.median(1e3 * run["phase_seconds"][phase] / run[count] for run in runs)

    return (
        f"{phase_table(runs)}\n\nMedians over {len(runs)} seeds, evaluated every "
        f"{_spaced(int(interval))} frames: {_spaced(statistics.median(r['updates'] for r in runs))}"
        f" updates at {per('update', 'updates'):.2f} ms each with their sampling; collecting "
        f"{per('collect', 'frames'):.3f} ms and storing {per('store', 'frames'):.3f} ms a frame."
    )


# the peers the README and the targets name, in their words, in the order they are named
PEER_TITLES = {"sb3_dqn": "Stable-Baselines3", "sbx_dqn": "SBX"}


# docs/performance.md's CartPole targets: the default's median seconds to solve, and its lead
# on the interquartile means of Stable-Baselines3 and of SBX (intervals apart)
SOLVE_SECONDS_TARGET = 5.0
LEAD_TARGETS = {"sb3_dqn": 6.0, "sbx_dqn": 1.0}  # a peer's IQM over ours, at least


def performance_targets() -> str:
    """docs/performance.md's CartPole targets, each preset of the 20-seed run (the default and
    ``dqn+fast=true``) against each, one column per evaluation protocol, from
    ``docs/results/performance.json``: every seed solved; the median seconds to solve at most
    :data:`SOLVE_SECONDS_TARGET`; the interquartile mean at least a peer's factor of
    :data:`LEAD_TARGETS` below the peer's, the 95 % intervals apart."""
    from benchmarks.harness import PEERS
    from trl_cartpole.tools.comparison import iqm_to_solve, median_to_solve

    protocols = json.loads(PERFORMANCE.read_text())["protocols"]
    first = next(iter(protocols.values()))
    header = " | ".join(f"every {_spaced(int(interval))} frames" for interval in protocols)
    rows = [f"| target | preset | {header} | met |", "| --- " * (3 + len(protocols)) + "|"]
    for preset in (name for name in first if name not in PEERS):
        cells: dict[str, list[tuple[str, bool]]] = {}  # target -> (measured, met) per protocol
        for results in protocols.values():
            seconds = [run["seconds_to_solve"] for run in results[preset]]
            solved = sum(run["solved"] for run in results[preset])
            cells.setdefault("every seed solved", []).append(
                (f"{solved}/{len(seconds)}", solved == len(seconds))
            )
            median = median_to_solve(seconds)
            slowest = max(math.inf if value is None else value for value in seconds)
            cells.setdefault(f"median seconds to solve <= {SOLVE_SECONDS_TARGET:.0f} s", []).append(
                (f"median {median:.1f} s, slowest {slowest:.1f} s", median <= SOLVE_SECONDS_TARGET)
            )
            ours = iqm_to_solve(seconds)
            for peer, factor in LEAD_TARGETS.items():
                if peer not in results:
                    continue
                title = PEER_TITLES[peer]
                theirs = iqm_to_solve([run["seconds_to_solve"] for run in results[peer]])
                apart, ratio = theirs.low > ours.high, theirs.value / ours.value
                lead = f"{factor:.0f}x below {title}'s" if factor > 1 else f"below {title}'s"
                cells.setdefault(f"interquartile mean {lead}, 95 % intervals apart", []).append(
                    (
                        f"{theirs} s against {ours} s, {ratio:.1f}x, "
                        + ("apart" if apart else "overlapping"),
                        apart and ratio >= factor,
                    )
                )
        for target, measured in cells.items():
            met = "yes" if all(ok for _, ok in measured) else "no"
            rows.append(f"| {target} | {preset} | {' | '.join(m for m, _ in measured)} | {met} |")
    return "\n".join(rows)


def readme_results() -> str:
    """The README's results table: CartPole and the other env presets against
    Stable-Baselines3 and SBX where a file has them (interquartile means of seconds to solve,
    from ``docs/results/performance.json`` and ``race_<env>.json``; a preset run with overrides
    of its own, ``dqn+fast=true``, in brackets after the default), and Breakout's scores (the
    preset's seeds, :data:`ATARI_PRESET_FORM`, and the Atari-100k runs), one row each."""
    from benchmarks.harness import PEERS

    rows = [
        "| result | trl_cartpole | peer | measured on |",
        "| --- | --- | --- | --- |",
    ]
    sources = [("CartPole-v1", PERFORMANCE, "docs/performance.md#headline")]
    sources += [
        (_race_env_id(env), path, "docs/results/peers.md#the-other-envs-against-stable-baselines3")
        for env, path in RACES.items()
        if path.is_file()
    ]
    for env_id, path, link in sources:
        record = json.loads(path.read_text())
        for interval, results in record["protocols"].items():
            algo, *variants = [name for name in results if name not in PEERS]
            ours = _iqm_cell(results[algo]) + "".join(  # dqn+fast=true: " (`fast=true`: 7.9 s)"
                f" (`{variant.partition('+')[2]}`: {_iqm_cell(results[variant])})"
                for variant in variants
            )
            theirs = "; ".join(
                f"{title}: {_iqm_cell(results[peer])}"
                for peer, title in PEER_TITLES.items()
                if peer in results
            )
            rows.append(
                f"| {env_id}: seconds of training to solve, interquartile mean of "
                f"{len(results[algo])} seeds, evaluated every {_spaced(int(interval))} frames | "
                f"{ours} | {theirs} | [{record['machine']['cpu']}, {record['date']}]({link}) |"
            )
    rows += _readme_atari_rows()
    return "\n".join(rows)


def _race_env_id(env: str) -> str:
    import yaml

    preset = yaml.safe_load((PACKAGE / "configs" / "env" / f"{env}.yaml").read_text())
    return preset["env"]["id"]


def _iqm_cell(runs: list[dict]) -> str:
    """The interquartile mean of the runs' seconds to solve, an unsolved run infinitely slow."""
    from trl_cartpole.tools.comparison import iqm_to_solve

    return _seconds_cell(iqm_to_solve([run["seconds_to_solve"] for run in runs]).value)


def _seconds_cell(seconds: float) -> str:
    return f"{seconds:.1f} s" if math.isfinite(seconds) else "more than a quarter unsolved"


def _readme_atari_rows() -> list[str]:
    """Breakout's rows (the preset's seeds with bfloat16 on AVX-512 BF16, then on processors
    without AVX-512; each seed's best policy over 30 whole games) and one row per Atari-100k
    game beside DrQ(epsilon)'s published mean."""
    rows = []
    if ATARI_PRESET_FORM.is_file():
        record = json.loads(ATARI_PRESET_FORM.read_text())
        where = f"{record['machine']['cpu']}, {record['date']}"
        rows.append(_breakout_row(record["runs"], "2 hours, bfloat16 on AVX-512 BF16", where))
    if ATARI_AVX2.is_file():
        runs = json.loads(ATARI_AVX2.read_text())["runs"]
        kinds = ", ".join(dict.fromkeys(NUMBER_TYPES[run["autocast"]] for run in runs))
        machines = ", ".join(dict.fromkeys(_trained_on(run) for run in runs))
        where = f"{machines}, {max(run['measured']['date'] for run in runs)}"
        rows.append(_breakout_row(runs, f"2 hours, {kinds} on AVX2", where))
    if ATARI_100K.is_file():
        record = json.loads(ATARI_100K.read_text())
        for run in _atari_100k_runs(record):
            drq = ATARI_100K_PUBLISHED.get(run["env_id"], {}).get("DrQ(epsilon)")
            rows.append(
                f"| {_game_name(run['env_id'])}, Atari-100k (100 000 steps): the best policy's "
                f"mean over {run['final_eval_episodes']} games, one seed | "
                f"{run['final_eval_return_mean']:.1f} | "
                + (f"DrQ(epsilon), published: {drq:.1f}" if drq is not None else "")
                + f" | [{record['machine']['cpu']}, {record['date']}](docs/results/breakout.md) |"
            )
    return rows


# summary.json's autocast: the update's number type
NUMBER_TYPES = {"none": "float32", "bfloat16": "bfloat16"}


def _breakout_row(runs: list[dict], conditions: str, where: str) -> str:
    """A README row of Breakout seeds trained under ``conditions``, measured ``where``."""
    scores = ", ".join(f"{run['final_eval_return_mean']:.1f}" for run in runs)
    seeds = ", ".join(str(run["seed"]) for run in runs)
    return (
        f"| Breakout (`env=breakout`, {conditions}): the best policy's mean over 30 whole games, "
        f"seed{'s' * (len(runs) > 1)} {seeds} | {scores} | the Practical RL DQN assignment's "
        f"goal: {ATARI_TARGET['score']:g} | [{where}](docs/results/breakout.md) |"
    )


def _trained_on(run: dict) -> str:
    """The processor a recorded Atari run trained on, with its kernels' limits: the run's own
    ``cpu_kernels`` where its summary has them, else the record's measurement's."""
    machine = run["measured"]["machine"]
    return machine["cpu"] + _held(run.get("cpu_kernels") or machine.get("kernels", {}))


def _held(kernels: dict) -> str:
    """`` (oneDNN, ATen held to AVX2)`` for kernels held below the processor's instructions
    (``trl_cartpole.run.summary.ISA_LIMITS``): the libraries held to each level; else ``""``."""
    from trl_cartpole.run.summary import ISA_LIMITS

    levels: dict[str, list[str]] = {}
    for name, level in kernels.get("limits", {}).items():
        levels.setdefault(level.upper(), []).append(ISA_LIMITS[name])
    held = "; ".join(f"{', '.join(names)} held to {level}" for level, names in levels.items())
    return f" ({held})" if held else ""


def _spaced(number: float) -> str:
    """``12 345``: a whole number as the docs write it."""
    return f"{number:,.0f}".replace(",", " ")


def _seed_rows(runs: list[dict], target: float) -> list[str]:
    """A table of env runs seed by seed (``python -m benchmarks envs ... --record``): frames,
    training seconds, the evaluation curve, the first evaluation at or above ``target``, the
    policies played again before one was kept, the final 100 episodes, speed and memory."""
    rows = [
        "| seed | frames | train s | greedy return at each evaluation | first evaluation >= "
        f"{target:g}: frames, train s | best | candidates: frames, evaluation -> new "
        "episodes (the chosen one in bold) | final (100 episodes) | frames/s, updates/s | "
        "peak memory, MiB |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for run in runs:
        curve, finals = run["eval_curve"], run["final_eval_returns"]
        reached = next(
            (
                f"{_spaced(frames)}, {_spaced(seconds)}"
                for frames, seconds, value in zip(
                    curve["frames"], curve["seconds"], curve["returns"], strict=True
                )
                if value >= target
            ),
            "never",
        )
        rows.append(
            f"| {run['seed']} | {_spaced(run['frames'])} | {_spaced(run['train_seconds'])} | "
            f"{', '.join(f'{value:.0f}' for value in curve['returns'])} | {reached} | "
            f"{run['best_eval_return_mean']:.1f} | {_candidates_cell(run)} | "
            f"{run['final_eval_return_mean']:.1f} +/- "
            f"{run['final_eval_return_std']:.1f} ({min(finals):.0f} to {max(finals):.0f}) | "
            f"{run['collect_frames_per_second']}, {run['updates_per_second']} | "
            f"{_spaced(run['peak_rss_mb'])} |"
        )
    return rows


def pixel_seeds() -> str:
    """docs/environments-measured.md's per-seed table of ``env=cartpole_pixels``, from
    ``docs/results/cartpole_pixels.json`` (``python -m benchmarks envs --envs cartpole_pixels
    ... --record`` writes it), with the target's verdict."""
    from benchmarks.envs import target_met, target_text
    from benchmarks.harness import ENV_MEDIAN_TARGETS, PIXEL_BUDGET

    record = json.loads(PIXELS.read_text())
    runs = record["runs"]
    rows = _seed_rows(runs, ENV_MEDIAN_TARGETS["cartpole_pixels"])
    finals = [run["final_eval_return_mean"] for run in runs]
    within = all(run[key] <= limit for run in runs for key, limit in PIXEL_BUDGET.items())
    verdict = "met" if target_met("cartpole_pixels", finals) and within else "**not met**"
    budget = (
        f"within {PIXEL_BUDGET['train_seconds'] / 60:g} minutes of training and "
        f"{PIXEL_BUDGET['peak_rss_mb'] / 1024:g} GiB"
    )
    return _results_block(
        record,
        rows,
        f"Target ({target_text('cartpole_pixels')}, final 100-episode return on Gymnasium's "
        f"render() frames, {budget}): {verdict}.",
    )


def lunarlander_in_budget() -> str:
    """docs/performance.md's LunarLander runs stopped after a few minutes of training, seed
    by seed, from ``docs/results/lunarlander_300s.json`` (``python -m benchmarks envs --envs
    lunarlander ... collector.max_train_seconds=300 --record`` writes it), with the verdict of
    its target: every seed's best policy at or above 200 over 100 episodes in the budget."""
    from benchmarks.harness import ENV_TARGETS, LUNARLANDER_BUDGET_SECONDS

    record = json.loads(LUNARLANDER_IN_BUDGET.read_text())
    runs, target = record["runs"], ENV_TARGETS["lunarlander"]
    budget = LUNARLANDER_BUDGET_SECONDS + LUNARLANDER_TIME_SLACK_SECONDS
    met = [
        run["seed"]
        for run in runs
        if run["final_eval_return_mean"] >= target and run["train_seconds"] <= budget
    ]
    verdict = "met" if len(met) == len(runs) else "**not met**"
    return _results_block(
        record,
        _seed_rows(runs, target),
        f"Target (every seed's best policy >= {target:g} over 100 episodes within "
        f"{LUNARLANDER_BUDGET_SECONDS:g} s of training): {verdict}; {len(met)} of the "
        f"{len(runs)} seeds reach it.",
    )


def _results_block(record: dict, rows: list[str], verdict: str) -> str:
    """A results file's command, where and when it ran, its table and the target's verdict."""
    return "\n".join(
        [_fenced(record["command"], "bash"), provenance_line(record), "", *rows, "", verdict]
    )


def _candidates_cell(run: dict) -> str:
    """The policies a run played again before keeping one (``eval.candidates``), or "none"
    where it kept its best evaluation's as is."""
    scores = run.get("candidates")
    if not scores:
        return "none"
    cells = []
    for score in scores:
        cell = (
            f"{_spaced(score['frames'])}: {score['eval_return_mean']:.0f} -> "
            f"{score['replay_return_mean']:.1f}"
        )
        cells.append(f"**{cell}**" if score["frames"] == run["best_policy_frames"] else cell)
    return "; ".join(cells)


ATARI_TARGET = {"score": 15.0, "train_seconds": 2 * 3600, "peak_rss_mb": 4 * 1024, "seeds": 3}
# The loop reads its time limit after each batch, so a run its 2 hours end records up to one
# batch beyond them (0.3 s for the preset's 4 steps and 4 updates): 10 s of slack.
ATARI_TIME_SLACK_SECONDS = 10.0


def atari_runs() -> str:
    """docs/results/breakout.md's tables of Breakout runs, one per form of the recipe
    (:data:`ATARI_RECORDS`, written by ``python -m benchmarks atari --checkpoint RUN_DIR ...
    --record``), each with the Practical RL DQN assignment's target's verdict."""
    blocks = []
    for path, _, title in ATARI_RECORDS:
        if path.is_file():
            record = json.loads(path.read_text())
            budget = (
                ATARI_STRETCH_SECONDS if path == ATARI_STRETCH else ATARI_TARGET["train_seconds"]
            )
            blocks.append(
                f"**{title}.**\n\n{_results_block(record, *_atari_table(record, budget))}"
            )
    return "\n\n".join(blocks)


def _recorded_atari_forms() -> list[tuple[str, str, dict]]:
    """Each form of :data:`ATARI_RECORDS` whose results file exists, in order: the name of its
    seeds, its title and its record."""
    return [
        (seeds, title, json.loads(path.read_text()))
        for path, seeds, title in ATARI_RECORDS
        if path.is_file()
    ]


def atari_taper_ablation() -> str:
    """docs/results/breakout.md's table of the fourth form (no taper) trained on the fifth
    form's seeds (:data:`ATARI_NO_TAPER`), and a sentence setting each seed's best policy beside its
    tapered run's (:data:`ATARI_TAPERED`): the same seed, the same steps, the taper alone."""
    if not ATARI_NO_TAPER.is_file():
        return "Not measured yet."
    record = json.loads(ATARI_NO_TAPER.read_text())
    tapered = {run["seed"]: run for run in json.loads(ATARI_TAPERED.read_text())["runs"]}
    rows, _ = _atari_table(record)
    pairs = []
    for run in record["runs"]:
        if run["seed"] not in tapered:
            continue
        with_taper = tapered[run["seed"]]
        pairs.append(
            f"seed {run['seed']}, {run['final_eval_return_mean']:.1f} without the taper after "
            f"{_spaced(run['updates'])} updates and {with_taper['final_eval_return_mean']:.1f} "
            f"with it after {_spaced(with_taper['updates'])}"
        )
    comparison = f"The best policies over 30 whole games: {'; '.join(pairs)}." if pairs else ""
    return _results_block(record, rows, comparison)


def atari_100k() -> str:
    """docs/results/breakout.md's table of the Atari-100k runs (:data:`ATARI_100K`, written
    by ``python -m benchmarks atari --checkpoint RUN_DIR ... --record``) beside the published
    means of :data:`ATARI_100K_PUBLISHED`."""
    if not ATARI_100K.is_file():
        return "Not measured yet."
    record = json.loads(ATARI_100K.read_text())
    authors = list(dict.fromkeys(name for means in ATARI_100K_PUBLISHED.values() for name in means))
    rows = [
        "| game | seed | agent steps | train time | greedy score at each evaluation | "
        "best policy (steps) | final: 30 games | exported, in Gymnasium's loop: 30 games | "
        + " | ".join(f"{name}, published" for name in authors)
        + " |",
        "| --- " * (8 + len(authors)) + "|",
    ]
    for run in _atari_100k_runs(record):
        published = ATARI_100K_PUBLISHED.get(run["env_id"], {})
        rows.append(
            f"| {_game_name(run['env_id'])} | {run['seed']} | "
            f"{_spaced(run['frames'])} | {_duration(run['train_seconds'])} | "
            f"{', '.join(f'{value:.1f}' for value in run['eval_curve']['returns'])} | "
            f"{_spaced(run['best_policy_frames'])} | {run['final_eval_return_mean']:.1f} +/- "
            f"{run['final_eval_return_std']:.1f} | {run['plain_loop']['mean']:.1f} +/- "
            f"{run['plain_loop']['std']:.1f} | "
            + " | ".join(f"{published[name]:.1f}" if name in published else "-" for name in authors)
            + " |"
        )
    return "\n".join([_fenced(record["command"], "bash"), provenance_line(record), "", *rows])


def _game_name(env_id: str) -> str:
    """``ALE/Breakout-v5`` -> ``Breakout``."""
    return env_id.split("/")[-1].split("-")[0]


def _atari_100k_runs(record: dict) -> list[dict]:
    """The Atari-100k runs in :data:`ATARI_100K_PUBLISHED`'s order of games (others last)."""
    order = list(ATARI_100K_PUBLISHED)

    def place(run: dict) -> tuple[int, int]:
        game = run["env_id"]
        return order.index(game) if game in order else len(order), run["seed"]

    return sorted(record["runs"], key=place)


def atari_loop_seeds() -> str:
    """docs/results/breakout.md's table of best policies over many games of Gymnasium's loop
    (:data:`ATARI_LOOP_SEEDS`): its first :data:`ATARI_LOOP_FIRST_GAMES` games, the games of the
    recipe's tables, against the games after them, and the run's own final evaluation on its own
    games; each difference with its standard error (from the games' spreads)."""
    record = json.loads(ATARI_LOOP_SEEDS.read_text())
    first = ATARI_LOOP_FIRST_GAMES
    plays = [run["plain_loop"] for run in record["runs"]]
    (games,) = {play["games"] for play in plays}  # one count of games for every policy
    (start,) = {play["first_seed"] for play in plays}
    (own_games,) = {run["final_eval_episodes"] for run in record["runs"]}
    rest, seeds = games - first, f"{start} to {start + first - 1}"
    rows = [
        f"| run's seed | the run's own final evaluation: {own_games} games | Gymnasium's loop: "
        f"{first} games seeded {seeds} | the {rest} games after them | first {first} minus the "
        f"{rest} | own evaluation minus the {rest} |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    kinder, own_gaps, errors = _loop_first_games_gaps(record), [], []
    for run, play, gap in zip(record["runs"], plays, kinder, strict=True):
        head, tail = play["scores"][:first], play["scores"][first:]
        tail_variance = statistics.pvariance(tail) / rest
        errors.append(math.sqrt(statistics.pvariance(head) / first + tail_variance))
        own = run["final_eval_return_mean"]
        own_gaps.append(own - statistics.mean(tail))
        rows.append(
            f"| {run['seed']} | {own:.1f} | {statistics.mean(head):.1f} | "
            f"{statistics.mean(tail):.1f} | {gap:+.1f} | {own_gaps[-1]:+.1f} |"
        )
    higher = sum(gap > 0 for gap in kinder)
    summary = (
        f"The first {first} games score higher than the {rest} after them for {higher} of the "
        f"{len(kinder)} policies (by {statistics.median(kinder):+.1f} points, the median); the "
        f"run's own evaluation against the same {rest}: {statistics.median(own_gaps):+.1f} (the "
        f"median). Each row's difference carries about {statistics.median(errors):.1f} points of "
        "noise (one standard error, the median over the rows)."
    )
    return _results_block(record, rows, summary)


def atari_loop_gap() -> str:
    """docs/results/breakout.md's sentence on the recipe's tables (:data:`ATARI_RECORDS`): on
    how many seeds the best policy scores higher in Gymnasium's loop than in the run's own final
    evaluation, by how much (the median and range), and the seeds that score lower."""
    runs = [run for _, _, record in _recorded_atari_forms() for run in record["runs"]]
    gaps = [run["plain_loop"]["mean"] - run["final_eval_return_mean"] for run in runs]
    higher = sorted(gap for gap in gaps if gap > 0)
    lower = [
        f"{run['seed']} by {-gap:.1f}" if gap < 0 else f"{run['seed']} level"
        for run, gap in zip(runs, gaps, strict=True)
        if gap <= 0
    ]
    largest = runs[gaps.index(max(gaps))]
    span = f"by {higher[0]:.1f} to {higher[-1]:.1f} points, " if higher else ""
    return (
        "Exported into Gymnasium's own loop, the best policies score higher than in the run's "
        f"own final evaluation on {len(higher)} of the {len(runs)} seeds of these tables "
        f"({span}a median of {statistics.median(gaps):+.1f} over all of them; "
        f"{'lower or level: seed ' + ', '.join(lower) if lower else 'none lower'}; the largest "
        f"seed {largest['seed']}'s, {largest['plain_loop']['mean']:.1f} against "
        f"{largest['final_eval_return_mean']:.1f})."
    )


def _loop_first_games_gaps(record: dict) -> list[float]:
    """Each policy's mean over Gymnasium's loop's first :data:`ATARI_LOOP_FIRST_GAMES` games
    minus its mean over the games after them."""
    first = ATARI_LOOP_FIRST_GAMES
    return [
        statistics.mean(run["plain_loop"]["scores"][:first])
        - statistics.mean(run["plain_loop"]["scores"][first:])
        for run in record["runs"]
    ]


def atari_torchrl_settings() -> str:
    """docs/results/breakout.md's table of the run of TorchRL's DQN Atari example's settings
    (:data:`ATARI_TORCHRL_SETTINGS`), with the target's verdict as the recipe's tables."""
    if not ATARI_TORCHRL_SETTINGS.is_file():
        return "Not measured yet."
    record = json.loads(ATARI_TORCHRL_SETTINGS.read_text())
    return _results_block(record, *_atari_table(record))


def _hours(seconds: int) -> str:
    """``2 hours``, ``1 hour``: a whole number of hours as the docs write it."""
    return f"{seconds // 3600} hour{'s' * (seconds != 3600)}"


def _meets_atari_target(run: dict, train_seconds: int = ATARI_TARGET["train_seconds"]) -> bool:
    """Whether one run's best policy meets :data:`ATARI_TARGET`'s score and memory within
    ``train_seconds`` of training (the target's 2 hours, or the stretch's 1)."""
    return (
        run["final_eval_return_mean"] >= ATARI_TARGET["score"]
        and run["train_seconds"] <= train_seconds + ATARI_TIME_SLACK_SECONDS
        and run["peak_rss_mb"] <= ATARI_TARGET["peak_rss_mb"]
    )


def _atari_table(
    record: dict, train_seconds: int = ATARI_TARGET["train_seconds"]
) -> tuple[list[str], str]:
    """One record's rows and its verdict on :data:`ATARI_TARGET`, within ``train_seconds``."""
    rows = [
        "| seed | agent steps | updates | train time | greedy score at each evaluation | "
        "best policy (steps) | final: 30 games | exported, in Gymnasium's loop: 30 games | "
        "collecting: steps/s; updates/s | peak memory, MiB |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for run in record["runs"]:
        finals, plain = run["final_eval_returns"], run["plain_loop"]
        rows.append(
            f"| {run['seed']} | {_spaced(run['frames'])} | {_spaced(run['updates'])} | "
            f"{_duration(run['train_seconds'])} | "
            f"{', '.join(f'{value:.1f}' for value in run['eval_curve']['returns'])} | "
            f"{_spaced(run['best_policy_frames'])} | {run['final_eval_return_mean']:.1f} +/- "
            f"{run['final_eval_return_std']:.1f} ({min(finals):.0f} to {max(finals):.0f}) | "
            f"{plain['mean']:.1f} +/- {plain['std']:.1f} | "
            f"{run['collect_frames_per_second']}, {run['updates_per_second']} | "
            f"{_spaced(run['peak_rss_mb'])} |"
        )
    meeting = [run["seed"] for run in record["runs"] if _meets_atari_target(run, train_seconds)]
    seeds = ATARI_TARGET["seeds"]
    met = len(meeting) == len(record["runs"]) >= seeds
    verdict = (
        f"Target ({seeds} seeds, every one's best policy >= {ATARI_TARGET['score']:g} over 30 "
        f"whole games within {_hours(train_seconds)} of training and "
        f"{ATARI_TARGET['peak_rss_mb'] // 1024} GiB): {'met' if met else '**not met**'}; "
        f"{len(meeting)} of the {len(record['runs'])} seeds run here meet it"
        f"{' (' + ', '.join(map(str, meeting)) + ')' if meeting else ''}."
    )
    return rows, verdict


CHECKPOINT_COST = ROOT / "docs" / "results" / "checkpoint_cost.json"
# a checkpoint of a full pixel-preset buffer: what it writes beyond its new rows, its seconds,
# and the disk two checkpoints take, against one buffer (docs/reliability.md)
CHECKPOINT_TARGET = {"extra_share": 0.05, "seconds": 2.0, "disk_buffers": 1.2}


def checkpoint_cost() -> str:
    """``python -m benchmarks checkpoint-cost --record``'s table and its verdict."""
    from benchmarks.checkpoint_cost import LINKED, TABLE_HEAD, table_row

    record = json.loads(CHECKPOINT_COST.read_text())
    buffer = record["buffer"]
    whole_bytes = buffer["row_bytes"] * min(buffer["filled"], buffer["size"])
    new_bytes = buffer["row_bytes"] * buffer["added"]
    linked = next(row for row in record["rows"] if row["storage"] == LINKED)
    extra = (linked["second_written_bytes"] - new_bytes) / whole_bytes
    disk = linked["disk_bytes"] / whole_bytes
    met = (
        extra <= CHECKPOINT_TARGET["extra_share"]
        and linked["second_seconds"] <= CHECKPOINT_TARGET["seconds"]
        and disk <= CHECKPOINT_TARGET["disk_buffers"]
    )
    verdict = (
        f"The second checkpoint writes {extra:.2%} of the buffer's bytes beyond its "
        f"{_spaced(buffer['added'])} new rows in {linked['second_seconds']:.2f} s, and the two "
        f"checkpoints take {disk:.2f} times one buffer on disk. Target (at most "
        f"{CHECKPOINT_TARGET['extra_share']:.0%} beyond the new rows, "
        f"{CHECKPOINT_TARGET['seconds']:g} s, {CHECKPOINT_TARGET['disk_buffers']:g} buffers): "
        f"{'met' if met else '**not met**'}."
    )
    rows = [*TABLE_HEAD, *(table_row(row) for row in record["rows"])]
    return _results_block(record, rows, verdict)


UPDATE_COST = ROOT / "docs" / "results" / "update_cost.json"
# one update of the default's network (2x128 MLP) at batch 128, Adam, one core (docs/performance.md)
UPDATE_TARGET = {"overrides": ["buffer.batch_size=128"], "total_ms": 0.5}


def update_cost() -> str:
    """``python -m benchmarks update-cost --record``'s measurements, each a table, and the
    target's verdict."""
    from benchmarks.update_cost import COMPILED, TABLE_HEAD, summary_line, table_row

    record = json.loads(UPDATE_COST.read_text())
    parts = []
    for run in record["runs"]:
        parts += [
            _fenced(run["command"], "bash"),
            provenance_line(run) + (f" {run['note']}" if run.get("note") else ""),
            "",
            *TABLE_HEAD,
            *(table_row(row) for row in run["rows"]),
            "",
            summary_line(run) + _against_float32(run, record["runs"]),
            "",
        ]
    target = next(
        (run for run in record["runs"] if run["overrides"] == UPDATE_TARGET["overrides"]), None
    )
    if target is None:
        verdict = "Target (one update at batch 128 within 0.5 ms): not measured."
    else:
        compiled = next(row for row in target["rows"] if row["name"] == COMPILED)["total_ms"]
        met = compiled <= UPDATE_TARGET["total_ms"]
        verdict = (
            f"Target (one update of the default's network at batch 128, one core, within "
            f"{UPDATE_TARGET['total_ms']} ms): {compiled:.2f} ms compiled, "
            f"{'met' if met else '**not met**'}."
        )
    return "\n".join([*parts, verdict])


def atari_update_cost() -> str:
    """docs/atari.md's table of one Breakout update on each kind of processor measured: from
    the ``env=breakout`` runs of ``docs/results/update_cost.json``."""
    from benchmarks.update_cost import CHANNELS_LAST, COMPILED

    rows = [
        "| processor | number type | threads | ms per update, eager | compiled | channels-last |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    runs = json.loads(UPDATE_COST.read_text())["runs"]
    for run in (run for run in runs if "env=breakout" in run["overrides"]):
        units, kernels = run["machine"]["vector_units"], run["machine"].get("kernels", {})
        native = kernels.get("computes_bfloat16", "avx512_bf16" in units or "amx_bf16" in units)
        processor = (
            "AVX-512 BF16"
            if "avx512_bf16" in units
            else "AVX-512"
            if "avx512f" in units
            else "AVX2"
        )
        processor += _held(kernels)
        bfloat16 = "optim.autocast=bfloat16" in run["overrides"]
        kind = ("bfloat16" + ("" if native else " (emulated)")) if bfloat16 else "float32"
        total = {row["name"]: row["total_ms"] for row in run["rows"]}
        rows.append(
            f"| {run['machine']['cpu']}, {processor} | {kind} | {run['num_threads']} "
            f"| {total['dqn']:.1f} | {total[COMPILED]:.1f} | "
            + (f"{total[CHANNELS_LAST]:.1f} |" if CHANNELS_LAST in total else "- |")
        )
    return "\n".join(rows)


def _against_float32(run: dict, runs: list[dict]) -> str:
    """For a run with ``optim.autocast=bfloat16``: its updates over the same run's in float32
    (the measurement with the same overrides less that one, or with ``optim.autocast=none`` in
    its place for a preset that sets bfloat16), where both were recorded."""
    from benchmarks.update_cost import COMPILED

    autocast, none = "optim.autocast=bfloat16", "optim.autocast=none"
    if autocast not in run["overrides"]:
        return ""
    plain = [override for override in run["overrides"] if override != autocast]
    float32 = next(
        (
            other
            for other in runs
            if [override for override in other["overrides"] if override != none] == plain
            and other["machine"]["vector_units"] == run["machine"]["vector_units"]
            and _held(other["machine"].get("kernels", {}))
            == _held(run["machine"].get("kernels", {}))
        ),
        None,
    )
    if float32 is None:
        return ""
    eager = {r["name"]: r["total_ms"] for r in float32["rows"]}["dqn"]
    short = {"dqn": "eager", COMPILED: "compiled"}
    ratios = ", ".join(
        f"{short[row['name']]} {row['total_ms'] / eager:.2f}"
        for row in run["rows"]
        if row["name"] in short
    )
    return f"; bfloat16 against float32 eager ({eager:.2f} ms): {ratios}"


def train_listing() -> str:
    """``train()`` as ``src/trl_cartpole/run/training.py`` has it."""
    from trl_cartpole.run.training import train

    return _fenced(inspect.getsource(train), "python")


PACKAGE = ROOT / "src" / "trl_cartpole"


def _summary(path: Path) -> str:
    """A module's docstring's first paragraph, on one line (``a`` for ``:mod:`~x.a```)."""
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    text = " ".join(doc.split("\n\n")[0].split()).replace("``", "`")
    return re.sub(r":\w+:`~?([^`]+)`", lambda m: f"`{m.group(1).rsplit('.', 1)[-1]}`", text)


def _layers() -> list[list[str]]:
    """The import-linter layers of ``pyproject.toml``, top first: each a list of names."""
    import tomllib  # Python 3.11+, as the maintainer's tools are

    contract = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    layers = contract["contracts"][0]["layers"]
    return [[n.strip().split(".")[-1] for n in re.split(r"[|:]", layer)] for layer in layers]


def _folder_name(name: str) -> str:
    return f"`{name}/`" if (PACKAGE / name).is_dir() else f"`{name}.py`"


def folder_table() -> str:
    """The package's folders in their import layers, each with its ``__init__`` docstring (a
    folder imports only from the layers below its own; those of one layer not each other)."""
    layers = [[n for n in layer if n not in ("__main__", "trl_cartpole")] for layer in _layers()]
    rows = ["| folder | owns | may import |", "| --- | --- | --- |"]
    for index, layer in enumerate(layers):
        lower = layers[index + 1] if index + 1 < len(layers) else []
        may = f"{', '.join(map(_folder_name, lower))} and below" if lower else "nothing"
        for name in layer:
            init = PACKAGE / name / "__init__.py"
            owns = _summary(init if init.exists() else PACKAGE / f"{name}.py")
            rows.append(f"| {_folder_name(name)} | {owns} | {may} |")
    return "\n".join(rows)


def module_table() -> str:
    """Every module of the package with its docstring's first paragraph, folder by folder."""
    order = [n for layer in _layers() for n in layer if n not in ("__main__", "trl_cartpole")]
    rows = ["| module | owns |", "| --- | --- |"]
    for name in order:
        folder = PACKAGE / name
        paths = sorted(folder.rglob("*.py")) if folder.is_dir() else [PACKAGE / f"{name}.py"]
        for path in paths:
            if path.name != "__init__.py":
                rows.append(f"| `{path.relative_to(PACKAGE)}` | {_summary(path)} |")
    return "\n".join(rows)


def factory_defaults() -> str:
    """Each factory's defaults beside TorchRL's, and what it returns, read off the signatures."""
    from maintain.reference import defaults_table

    return defaults_table()


BLOCKS: dict[str, tuple[str, Callable[[], str]]] = {
    "readme-ending": ("README.md", readme_ending),
    "readme-next-steps": ("README.md", readme_next_steps),
    "readme-results": ("README.md", readme_results),
    "config-fields": ("docs/reference/config.md", config_fields),
    "algo-presets": ("docs/guide.md", algo_presets),
    "train-listing": ("docs/architecture.md", train_listing),
    "folder-table": ("docs/architecture.md", folder_table),
    "module-table": ("docs/architecture.md", module_table),
    "performance-tables": ("docs/performance.md", performance_tables),
    "performance-phases": ("docs/performance.md", performance_phases),
    "performance-targets": ("docs/performance.md", performance_targets),
    "pixel-seeds": ("docs/environments-measured.md", pixel_seeds),
    "lunarlander-in-budget": ("docs/results/peers.md", lunarlander_in_budget),
    "atari-runs": ("docs/results/breakout.md", atari_runs),
    "atari-100k": ("docs/results/breakout.md", atari_100k),
    "atari-loop-gap": ("docs/results/breakout.md", atari_loop_gap),
    "atari-taper-ablation": ("docs/results/breakout.md", atari_taper_ablation),
    "atari-loop-seeds": ("docs/results/breakout.md", atari_loop_seeds),
    "atari-torchrl-settings": ("docs/results/breakout.md", atari_torchrl_settings),
    "checkpoint-cost": ("docs/reliability.md", checkpoint_cost),
    "update-cost": ("docs/results/speed.md", update_cost),
    "atari-update-cost": ("docs/atari.md", atari_update_cost),
    **{
        f"race-{env}": ("docs/results/peers.md", partial(performance_tables, path))
        for env, path in RACES.items()
    },
    "factory-defaults": ("docs/reference/factories.md", factory_defaults),
}


def _pattern(name: str) -> re.Pattern[str]:
    return re.compile(rf"<!-- generated:{name} -->.*?<!-- /generated:{name} -->", re.DOTALL)


def stale_blocks(write: bool = False) -> list[str]:
    """The blocks whose text differs from their source (rewritten in place with ``write``)."""
    stale = []
    for name, (doc, generate) in BLOCKS.items():
        path = ROOT / doc
        text = path.read_text()
        match = _pattern(name).search(text)
        if match is None:
            stale.append(f"{doc}: no <!-- generated:{name} --> block")
            continue
        expected = f"<!-- generated:{name} -->\n{generate()}\n<!-- /generated:{name} -->"
        if match.group(0) != expected:
            stale.append(f"{doc}: {name}")
            if write:
                path.write_text(text[: match.start()] + expected + text[match.end() :])
    return stale


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--check", action="store_true", help="write nothing; exit 1 if a block is stale"
    )


def main(args: argparse.Namespace) -> None:
    stale = stale_blocks(write=not args.check)
    if args.check and stale:
        print("stale generated docs (python -m maintain docs):", *stale, sep="\n  ")
        sys.exit(1)
    print("rewrote: " + ", ".join(stale) if stale else "every generated block is up to date")
