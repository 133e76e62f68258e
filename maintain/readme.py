"""Run the README's quick start and next steps, time each, write ``docs/results/readme.json``.

Each command runs as the README writes it, one at a time from the repository root, timed from
start to exit; the quick start's printed ending and its plots (``durations.png``,
``dashboard.png``, copied to ``docs/images/``) become the README's. ``python -m maintain
docs`` then regenerates the README's blocks from the results file. ``--check-run RUN_DIR``
instead compares a run of the quick start (CI's) with the recorded one: on the same CPU model
the frames to solve and the final return must be equal (a seed's run follows the CPU's float
kernels); on another (another model name or vector units), the difference is reported and not
failed.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.harness import provenance

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "docs" / "results" / "readme.json"
PYTHON = ".venv/bin/python"  # as the README writes it

QUICK_START = f"{PYTHON} scripts/train.py"
# (command as the README writes it, what it does, timed)
NEXT_STEPS = [
    (f"{PYTHON} scripts/train.py --help", "every preset and field", True),
    (f"{PYTHON} scripts/evaluate.py checkpoint=runs/latest", "100 greedy episodes", True),
    (
        f"{PYTHON} scripts/render.py checkpoint=runs/latest",
        "runs/latest/checkpoints/video.gif",
        True,
    ),
    (f"{PYTHON} scripts/train.py seed=1", "another seed; any field: key=value", True),
    (f"{PYTHON} scripts/train.py algo=double", "a DQN variant", True),
    (f"{PYTHON} scripts/train.py algo=rainbow", "all of them together", True),
    (f"{PYTHON} scripts/train.py algo=tutorial", "the PyTorch DQN tutorial's settings", True),
    (f"{PYTHON} scripts/train.py env=acrobot", "Acrobot-v1, tuned preset", True),
    (
        f"{PYTHON} scripts/train.py env.id=Acrobot-v1",
        "any Gymnasium id, CartPole's settings",
        True,
    ),
    (
        f"{PYTHON} scripts/train.py resume=runs/latest",
        "after Ctrl-C: continue where it stopped",
        False,
    ),
]


def _run(command: str) -> tuple[float, str]:
    """Run ``command`` (its ``.venv/bin/python`` is this interpreter): seconds and stdout."""
    argv = [sys.executable if word == PYTHON else word for word in command.split()]
    start = time.perf_counter()
    proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - start
    if proc.returncode != 0:
        raise SystemExit(f"error: {command} exited {proc.returncode}: {proc.stderr[-500:]}")
    return seconds, proc.stdout


def record() -> dict[str, object]:
    seconds, stdout = _run(QUICK_START)
    ending = stdout[stdout.index("CartPole-v1 [") :].rstrip("\n")
    run_dir = (ROOT / "runs" / "latest").resolve()
    summary = json.loads((run_dir / "summary.json").read_text())
    for image in ("durations.png", "dashboard.png"):
        shutil.copyfile(run_dir / image, ROOT / "docs" / "images" / image)
    steps = []
    for command, what, timed in NEXT_STEPS:
        step: dict[str, object] = {"command": command, "what": what}
        if timed:
            step["seconds"] = round(_run(command)[0], 1)
            # the later steps evaluate the quick start's run, not the one a step just made
            latest = ROOT / "runs" / "latest"
            latest.unlink()
            latest.symlink_to(run_dir.name)
        steps.append(step)
    return {
        **provenance(),
        "quick_start": {
            "command": QUICK_START,
            "seconds": round(seconds, 1),
            "ending": ending,
            "frames_to_solve": summary["frames_to_solve"],
            "seconds_to_solve": summary["seconds_to_solve"],
            "final_eval_return_mean": summary["final_eval_return_mean"],
            "evaluations": len(summary["eval_curve"]["frames"]),
        },
        "next_steps": steps,
    }


def check_run(run_dir: Path) -> None:
    """Compare a quick-start run with the recorded one (see the module docstring)."""
    recorded = json.loads(RESULTS.read_text())
    summary = json.loads((run_dir / "summary.json").read_text())
    expected = recorded["quick_start"]
    found = {
        "frames_to_solve": summary["frames_to_solve"],
        "final_eval_return_mean": summary["final_eval_return_mean"],
        "evaluations": len(summary["eval_curve"]["frames"]),
    }
    differ = {key: (expected[key], value) for key, value in found.items() if expected[key] != value}
    if not differ:
        print(f"the quick start ran as the README says: {found}")
        return
    machine = provenance()["machine"]
    here = machine["cpu"]
    same_cpu = all(machine[key] == recorded["machine"].get(key) for key in ("cpu", "vector_units"))
    detail = ", ".join(f"{key} {old} -> {new}" for key, (old, new) in differ.items())
    if same_cpu:
        print(
            f"error: the quick start no longer runs as the README says ({detail}); "
            "python -m maintain readme && python -m maintain docs"
        )
        sys.exit(1)
    print(
        f"note: on {here} (the README's run: {recorded['machine']['cpu']}) "
        f"the quick start differs ({detail}): another CPU's float kernels"
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--check-run", type=Path, default=None, help="compare this run directory, run nothing"
    )


def main(args: argparse.Namespace) -> None:
    if args.check_run is not None:
        check_run(args.check_run)
        return
    results = record()
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {RESULTS.relative_to(ROOT)}; now: python -m maintain docs")
