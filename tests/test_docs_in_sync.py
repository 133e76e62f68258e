"""The docs cannot drift: generated blocks match their sources, and the module table the code."""

from __future__ import annotations

import json
import re

import pytest

from maintain import docs

from .conftest import ROOT


def test_every_generated_block_matches_its_source():
    """Each ``<!-- generated:NAME -->`` block is what ``python -m maintain docs`` writes."""
    assert docs.stale_blocks(write=False) == []


def test_the_architecture_table_names_every_module_of_the_package_and_no_other():
    package = ROOT / "src" / "trl_cartpole"
    modules = {  # folder/module.py (or module.py at the top), the subcommands as one folder
        path.relative_to(package).as_posix()
        for path in package.rglob("*.py")
        if path.name not in ("__init__.py", "__main__.py") and "commands" not in path.parts
    }
    table = (ROOT / "docs" / "architecture.md").read_text().split("## What each module owns")[1]
    named = set(re.findall(r"`((?:\w+/)?\w+\.py)`", table.split("\n\n", 2)[1]))
    assert modules - named == set(), "modules missing from docs/architecture.md"
    assert named - modules == set(), "docs/architecture.md names modules that do not exist"


def test_the_architecture_page_gives_every_folder_of_the_package_its_concern():
    package = ROOT / "src" / "trl_cartpole"
    folders = {p.name for p in package.iterdir() if (p / "__init__.py").is_file()}
    table = (ROOT / "docs" / "architecture.md").read_text().split("## The folders")[1]
    assert folders == set(re.findall(r"^\| `(\w+)/` \|", table, re.MULTILINE))


# A command line in a doc: optional interpreter, then scripts/NAME.py or trl-cartpole NAME.
COMMAND = re.compile(
    r"^(?:\S*python\S*\s+)?(?:\S*scripts/(?P<script>\w+)\.py|trl-cartpole\s+(?P<sub>\w+))(?P<rest>.*)$"
)
SCHEMAS = {
    "evaluate": ("trl_cartpole.cli.commands.evaluate", "EvaluateArgs"),
    "render": ("trl_cartpole.cli.commands.render", "RenderArgs"),
    "export": ("trl_cartpole.cli.commands.export", "ExportArgs"),
    "tune": ("trl_cartpole.cli.commands.tune", "TuneArgs"),
    "plot": ("trl_cartpole.cli.commands.plot", "PlotArgs"),
}


def _documented_commands() -> list[tuple[str, str, list[str]]]:
    """``(where, subcommand, key=value arguments)`` of every command in a bash block of the docs."""
    import shlex

    found = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        for block in re.findall(r"```bash\n(.*?)```", path.read_text(), re.DOTALL):
            for line in block.replace("\\\n", " ").splitlines():
                for part in line.split("&&"):
                    match = COMMAND.match(part.strip())
                    if match is None:
                        continue
                    words = shlex.split(match["rest"], comments=True)
                    name = match["script"] or match["sub"]
                    found.append((path.name, name, [w for w in words if "=" in w]))
    return found


@pytest.mark.slow  # every documented command composed
def test_every_documented_command_line_is_one_the_code_accepts():
    """Each key of each documented command is a field its command knows, with a valid value."""
    import dataclasses
    import importlib

    from omegaconf import OmegaConf

    from trl_cartpole.config.compose import compose_config
    from trl_cartpole.config.schema import to_config
    from trl_cartpole.config.validation import validate

    commands = _documented_commands()
    assert len(commands) > 30  # the README and the guides are full of them
    refused = []
    for where, name, args in commands:
        # a placeholder (RUN_DIR, <run>), a user's own presets (presets=, a tuned preset the
        # docs write first) or a checkpoint path is not checkable here
        args = [a for a in args if not re.search(r"[<>]|[A-Z]{3,}|presets=|resume=|_tuned$", a)]
        # a sweep's "key=a,b" is checked at its first value
        args = [re.sub(r"=([^\[,]+),.*", r"=\1", a) for a in args]
        try:
            training = args
            if name in SCHEMAS:  # its own keys, then the training overrides it passes on
                module, schema = SCHEMAS[name]
                schema = getattr(importlib.import_module(module), schema)
                fields = {f.name for f in dataclasses.fields(schema)}
                own = [a for a in args if a.split("=", 1)[0] in fields or name != "tune"]
                OmegaConf.merge(OmegaConf.structured(schema), OmegaConf.from_dotlist(own))
                training = [a for a in args if a not in own] if name == "tune" else []
            if name in ("train", "tune") and training:
                validate(to_config(compose_config(overrides=training)))
        except Exception as error:
            refused.append(f"{where}: {name} {' '.join(args)}: {str(error).splitlines()[0]}")
    assert refused == []


def test_the_loop_seeds_table_gives_each_policy_its_own_difference(tmp_path, monkeypatch):
    """Each row of docs/atari.md's loop-seeds table: that policy's first 30 games minus the 70
    after them, computed here by hand."""
    first = docs.ATARI_LOOP_FIRST_GAMES

    def run(seed: int, head: float, tail: float) -> dict:
        scores = [head] * first + [tail] * (100 - first)
        play = {"games": 100, "first_seed": 0, "scores": scores, "mean": 0.0, "std": 0.0}
        return {
            "seed": seed,
            "final_eval_return_mean": 10.0,
            "final_eval_episodes": 30,
            "plain_loop": play,
        }

    machine = {"cpu": "test CPU", "cores": 2}
    record = {
        "date": "2026-11-29",
        "commit": "a" * 40,
        "machine": machine,
        "command": "c",
        "runs": [run(1, 12.0, 10.0), run(2, 9.0, 10.0), run(3, 15.0, 11.5)],
    }
    path = tmp_path / "atari_loop_seeds.json"
    path.write_text(json.dumps(record))
    monkeypatch.setattr(docs, "ATARI_LOOP_SEEDS", path)
    rows = [line for line in docs.atari_loop_seeds().splitlines() if line.startswith("| ")]
    # run's seed, own evaluation, first 30, the 70, first minus the 70, own minus the 70
    assert rows[2:] == [
        "| 1 | 10.0 | 12.0 | 10.0 | +2.0 | +0.0 |",
        "| 2 | 10.0 | 9.0 | 10.0 | -1.0 | +0.0 |",
        "| 3 | 10.0 | 15.0 | 11.5 | +3.5 | -1.5 |",
    ]
    assert "for 2 of the 3 policies (by +2.0 points, the median)" in docs.atari_loop_seeds()


def test_the_loop_gap_sentence_counts_every_form_of_the_recipe(tmp_path, monkeypatch):
    """docs/atari.md's sentence on the loop against the runs' own evaluations reads every
    recipe table's file that exists, with the differences computed here by hand."""

    def run(seed: int, own: float, loop: float) -> dict:
        return {"seed": seed, "final_eval_return_mean": own, "plain_loop": {"mean": loop}}

    first, second = tmp_path / "first.json", tmp_path / "second.json"
    first.write_text(json.dumps({"runs": [run(1, 10.0, 12.6), run(2, 14.0, 13.0)]}))
    second.write_text(json.dumps({"runs": [run(3, 11.0, 11.0), run(4, 9.0, 13.0)]}))
    records = [(first, "", ""), (tmp_path / "not-run.json", "", ""), (second, "", "")]
    monkeypatch.setattr(docs, "ATARI_RECORDS", tuple(records))
    # differences: +2.6, -1.0, 0.0, +4.0 -> 2 higher, median (0.0 + 2.6) / 2 = 1.3
    assert docs.atari_loop_gap() == (
        "Exported into Gymnasium's own loop, the best policies score higher than in the run's "
        "own final evaluation on 2 of the 4 seeds of these tables (by 2.6 to 4.0 points, a "
        "median of +1.3 over all of them; lower or level: seed 2 by 1.0, 3 level; the largest "
        "seed 4's, 13.0 against 9.0)."
    )


def test_the_readme_reports_the_preset_form_not_the_newest(tmp_path, monkeypatch):
    """The README's Breakout row reports the seeds of the form the preset sets
    (:data:`ATARI_PRESET_FORM`), not those of a newer form still training its seeds."""

    def run(seed: int, score: float) -> dict:
        return {
            "seed": seed,
            "final_eval_return_mean": score,
            "plain_loop": {"mean": score + 1.0},
            "train_seconds": 7_000.0,
            "peak_rss_mb": 1_500,
        }

    machine = {"cpu": "Some CPU", "cores": 2}
    preset, newer = tmp_path / "preset.json", tmp_path / "newer.json"
    preset.write_text(
        json.dumps(
            {
                "date": "2026-01-02",
                "machine": machine,
                "runs": [run(1, 16.0), run(2, 14.0), run(3, 15.0)],
            }
        )
    )
    newer.write_text(json.dumps({"date": "2026-01-03", "machine": machine, "runs": [run(4, 30.0)]}))
    records = [(preset, "the preset form's seeds", ""), (newer, "the newer form's seeds", "")]
    monkeypatch.setattr(docs, "ATARI_RECORDS", tuple(records))
    monkeypatch.setattr(docs, "ATARI_PRESET_FORM", preset)
    monkeypatch.setattr(docs, "ATARI_100K", tmp_path / "absent.json")
    monkeypatch.setattr(docs, "ATARI_AVX2", tmp_path / "absent.json")
    (row,) = docs._readme_atari_rows()
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert cells[0].endswith("seeds 1, 2, 3")
    assert cells[1] == "16.0, 14.0, 15.0"
    assert cells[3] == "[Some CPU, 2026-01-02](docs/results/breakout.md)"
    assert "30.0" not in row


def test_the_readme_names_each_avx2_seeds_machine_and_one_held_to_avx2(tmp_path, monkeypatch):
    def run(seed: int, score: float, machine: dict, date: str, **summary) -> dict:
        measured = {"date": date, "machine": machine}
        return {"seed": seed, "final_eval_return_mean": score, "measured": measured, **summary}

    real = {"cpu": "AMD EPYC", "vector_units": ["avx2", "fma"]}
    evaluated = {"cpu": "Intel Xeon", "kernels": {"torch": "AVX2", "limits": {"X": "AVX2"}}}
    held = {
        "torch": "AVX2",
        "limits": {"ONEDNN_MAX_CPU_ISA": "AVX2", "ATEN_CPU_CAPABILITY": "avx2"},
    }
    runs = [
        run(311, 16.04, real, "2026-12-02", autocast="none"),
        run(312, 15.46, evaluated, "2026-12-03", autocast="none", cpu_kernels=held),
    ]
    record = tmp_path / "avx2.json"
    record.write_text(json.dumps({"runs": runs}))
    monkeypatch.setattr(docs, "ATARI_PRESET_FORM", tmp_path / "absent.json")
    monkeypatch.setattr(docs, "ATARI_100K", tmp_path / "absent.json")
    monkeypatch.setattr(docs, "ATARI_AVX2", record)
    (row,) = docs._readme_atari_rows()
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert "2 hours, float32 on AVX2" in cells[0] and cells[0].endswith("seeds 311, 312")
    assert cells[1] == "16.0, 15.5"
    # the training's own limits, not the evaluation's
    trained_on = "AMD EPYC, Intel Xeon (oneDNN, ATen held to AVX2)"
    assert cells[3] == f"[{trained_on}, 2026-12-03](docs/results/breakout.md)"
    record.write_text(json.dumps({"runs": runs[:1]}))
    (row,) = docs._readme_atari_rows()
    assert "seed 311 |" in row  # one seed: singular


def test_the_readme_results_table_has_one_row_per_protocol_and_env():
    """One row per evaluation protocol of each comparison file, each with a figure on both
    sides, then the Atari rows: the table is the README's one results block."""
    table = docs.readme_results().splitlines()
    assert table[0] == "| result | trl_cartpole | peer | measured on |"
    cartpole = [row for row in table if row.startswith("| CartPole-v1")]
    protocols = json.loads(docs.PERFORMANCE.read_text())["protocols"]
    assert len(cartpole) == len(protocols)
    for row in cartpole:
        ours = r"[0-9.]+ s( \(`[^`]+`: [0-9.]+ s\))*"  # the default, then each variant
        assert re.search(rf"\| {ours} \| Stable-Baselines3: [0-9.]+ s", row), row


def test_the_readme_results_row_names_each_variant_and_peer(tmp_path, monkeypatch):
    """A comparison with the fast path and SBX: the default's IQM, then the variant's named by
    its overrides; Stable-Baselines3, then SBX. IQM of 1..8 s: the mean of 3..6 = 4.5 s."""
    runs = [{"seconds_to_solve": float(s)} for s in range(1, 9)]
    twice = [{"seconds_to_solve": 2.0 * s} for s in range(1, 9)]
    results = {"dqn": runs, "dqn+fast=true": twice, "sb3_dqn": twice, "sbx_dqn": runs}
    record = {"machine": {"cpu": "CPU"}, "date": "today", "protocols": {"1000": results}}
    path = tmp_path / "performance.json"
    path.write_text(json.dumps(record))
    monkeypatch.setattr(docs, "PERFORMANCE", path)
    monkeypatch.setattr(docs, "RACES", {})
    row = next(r for r in docs.readme_results().splitlines() if r.startswith("| CartPole-v1"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert cells[1:3] == ["4.5 s (`fast=true`: 9.0 s)", "Stable-Baselines3: 9.0 s; SBX: 4.5 s"]


def test_the_cartpole_targets_are_judged_per_preset_and_protocol(tmp_path, monkeypatch):
    """Seconds 1..8: IQM and median 4.5 s (<= 5); a peer at 10x those is 45 s, 10.0x, and its
    interval lies above ours; a peer at ours overlaps. An unsolved seed makes the slowest inf."""
    ours = [{"seconds_to_solve": float(s), "solved": True} for s in range(1, 9)]
    tenfold = [{"seconds_to_solve": 10.0 * s, "solved": True} for s in range(1, 9)]
    unsolved = [*ours[:7], {"seconds_to_solve": None, "solved": False}]
    results = {"dqn": ours, "dqn+fast=true": unsolved, "sb3_dqn": tenfold, "sbx_dqn": ours}
    path = tmp_path / "performance.json"
    path.write_text(json.dumps({"protocols": {"1000": results, "2500": results}}))
    monkeypatch.setattr(docs, "PERFORMANCE", path)
    rows = [
        [cell.strip() for cell in row.strip("|").split("|")]
        for row in docs.performance_targets().splitlines()
    ]
    assert rows[0] == ["target", "preset", "every 1 000 frames", "every 2 500 frames", "met"]
    judged = {(row[0], row[1]): row[2:] for row in rows[2:]}
    assert len(judged) == 2 * 4  # 4 targets for each of 2 presets
    assert judged["every seed solved", "dqn"] == ["8/8", "8/8", "yes"]
    assert judged["every seed solved", "dqn+fast=true"] == ["7/8", "7/8", "no"]
    median = "median seconds to solve <= 5 s"
    assert judged[median, "dqn"] == ["median 4.5 s, slowest 8.0 s"] * 2 + ["yes"]
    assert judged[median, "dqn+fast=true"][0] == "median 4.5 s, slowest inf s"
    sb3 = judged["interquartile mean 6x below Stable-Baselines3's, 95 % intervals apart", "dqn"]
    assert sb3[0].startswith("45.0 [") and sb3[0].endswith("10.0x, apart") and sb3[2] == "yes"
    sbx = judged["interquartile mean below SBX's, 95 % intervals apart", "dqn"]
    assert sbx[0].endswith("1.0x, overlapping") and sbx[2] == "no"


def test_the_taper_ablation_sets_each_seed_beside_its_tapered_run(tmp_path, monkeypatch):
    """docs/atari.md's ablation pairs each untapered seed with the same seed's tapered run (a
    seed without one is left out), and says "Not measured yet." before the file exists."""
    monkeypatch.setattr(docs, "ATARI_NO_TAPER", tmp_path / "no_taper.json")
    assert docs.atari_taper_ablation() == "Not measured yet."

    def run(seed: int, score: float, updates: int) -> dict:
        return {
            "seed": seed,
            "frames": updates + 1_608,
            "updates": updates,
            "train_seconds": 6_000.0,
            "eval_curve": {"returns": [1.0, score]},
            "best_policy_frames": 10_000,
            "final_eval_return_mean": score,
            "final_eval_return_std": 1.0,
            "final_eval_returns": [score - 1.0, score + 1.0],
            "plain_loop": {"mean": score, "std": 1.0},
            "collect_frames_per_second": 200,
            "updates_per_second": 30.0,
            "peak_rss_mb": 1_500,
        }

    head = {
        "date": "2026-11-29",
        "commit": "0123456789abcdef",
        "machine": {"cpu": "CPU", "cores": 2},
        "command": "python -m benchmarks atari --checkpoint RUN_DIR --games 30",
    }
    (tmp_path / "no_taper.json").write_text(
        json.dumps({**head, "runs": [run(7, 12.34, 198_392), run(8, 9.0, 1_000)]})
    )
    (tmp_path / "taper.json").write_text(json.dumps({**head, "runs": [run(7, 18.0, 198_392)]}))
    monkeypatch.setattr(docs, "ATARI_TAPERED", tmp_path / "taper.json")
    generated = docs.atari_taper_ablation()
    assert "| 8 | 2 608 | 1 000 |" in generated  # every untapered seed has its row
    assert generated.endswith(
        "The best policies over 30 whole games: seed 7, 12.3 without the taper after 198 392 "
        "updates and 18.0 with it after 198 392."
    )


@pytest.mark.parametrize("page", ["docs/atari.md", "docs/performance.md"])
def test_the_guide_pages_stay_guides(page):
    """How to use a thing stays short; studies live on the results pages they link to."""
    text = (ROOT / page).read_text()
    assert len(text.splitlines()) <= 250
    assert "results/" in text


def test_the_atari_update_table_names_the_processor_and_an_emulated_bfloat16(tmp_path, monkeypatch):
    from benchmarks.update_cost import CHANNELS_LAST, COMPILED

    def run(units: list[str], autocast: str, threads: int, eager: float) -> dict:
        rows = [{"name": "dqn", "total_ms": eager}, {"name": COMPILED, "total_ms": eager / 2}]
        overrides = ["env=breakout", f"optim.autocast={autocast}", f"num_threads={threads}"]
        machine = {"cpu": "test CPU", "cores": 2, "vector_units": units}
        return {"machine": machine, "overrides": overrides, "num_threads": threads, "rows": rows}

    native, avx2 = ["avx2", "avx512f", "avx512_bf16"], ["avx2", "fma"]
    cartpole = {**run(avx2, "none", 1, 1.0), "overrides": []}  # not Breakout: left out
    held = run(native, "none", 2, 40.0)  # an AVX-512 BF16 processor held to AVX2
    held["machine"]["kernels"] = {  # ATen not held: torch's own kernels stay AVX-512
        "torch": "AVX512",
        "computes_bfloat16": False,
        "limits": {"ONEDNN_MAX_CPU_ISA": "AVX2", "MKL_ENABLE_INSTRUCTIONS": "avx2"},
    }
    held["rows"].append({"name": CHANNELS_LAST, "total_ms": 36.0})
    runs = [run(native, "bfloat16", 1, 30.0), run(avx2, "bfloat16", 2, 600.0), cartpole, held]
    path = tmp_path / "update_cost.json"
    path.write_text(json.dumps({"runs": runs}))
    monkeypatch.setattr(docs, "UPDATE_COST", path)
    assert docs.atari_update_cost().splitlines()[2:] == [
        "| test CPU, AVX-512 BF16 | bfloat16 | 1 | 30.0 | 15.0 | - |",
        "| test CPU, AVX2 | bfloat16 (emulated) | 2 | 600.0 | 300.0 | - |",
        "| test CPU, AVX-512 BF16 (oneDNN, MKL held to AVX2) | float32 | 2 | 40.0 | 20.0 | 36.0 |",
    ]
