"""Hyperparameter search with Optuna: a YAML search space, pruned trials, a preset as the result.

A trial samples the fields of a search space (``configs/tune/<env>.yaml``) with Optuna's TPE
sampler (Bergstra et al. 2011), trains one run per seed with them, and scores them by one of
:data:`OBJECTIVES`: ``return`` (:func:`curve_score`, maximised: the mean greedy return over the
periodic evaluations of the frame budget, the area under the evaluation curve divided by its
length, where a run that stopped because it solved the env keeps its last value until the
budget), ``frames`` (:func:`frames_score`, minimised: the frames to solve, an unsolved run
counting twice its budget) or ``seconds`` (:func:`seconds_score`, minimised: the training
seconds to solve, an unsolved run counting twice the seconds it trained). Each evaluation is
reported to the trial, so Optuna's pruner (median rule by default) stops poor trials early. The
study lives in an Optuna storage (SQLite by default), so a stopped study resumes and several
processes share it. The best trial is written as a preset ``scripts/train.py`` takes by name.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from omegaconf import OmegaConf

from trl_cartpole.config.schema import flat_fields
from trl_cartpole.errors import ConfigError

if TYPE_CHECKING:  # the evaluation module imports torch: not at the tuner's import
    from trl_cartpole.run.evaluation import Evaluation

__all__ = [
    "OBJECTIVES",
    "curve_score",
    "frames_score",
    "load_search_space",
    "objective_overrides",
    "run_frames_score",
    "run_return_score",
    "run_seconds_score",
    "seconds_score",
    "seed_reporter",
    "suggest",
    "write_preset",
]

RANGE_KEYS = {"low", "high", "log", "step"}

OBJECTIVES = {"return": "maximize", "frames": "minimize", "seconds": "minimize"}
"""A trial's score and its direction: the mean greedy return over the evaluations, the frames
to solve, or the training seconds to solve."""


def load_search_space(path: str | Path) -> dict[str, dict[str, Any]]:
    """``{field: spec}`` from a YAML file; a spec is ``{low, high[, log, step]}`` or ``{choices}``.

    ``low``/``high`` integers give an integer range, floats a float range; a list among the
    choices (``[64, 64]``) is passed to the config as written.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"search space {str(path)!r} does not exist; pass --space FILE.yaml")
    space = yaml.safe_load(path.read_text()) or {}
    for name, spec in space.items():
        ok = isinstance(spec, dict) and (
            (set(spec) == {"choices"} and isinstance(spec["choices"], list) and spec["choices"])
            or ({"low", "high"} <= set(spec) <= RANGE_KEYS)
        )
        if not ok:
            raise ConfigError(
                f"search space {str(path)!r}: {name}: {spec!r} is neither "
                "{low: L, high: H[, log: true][, step: S]} nor {choices: [...]}"
            )
    return space


def suggest(trial: Any, space: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The values of one trial (``optuna.Trial``) for every field of ``space``."""
    params = {}
    for name, spec in space.items():
        if "choices" in spec:
            choices = [str(c) if isinstance(c, list) else c for c in spec["choices"]]
            params[name] = trial.suggest_categorical(name, choices)
        elif isinstance(spec["low"], int) and isinstance(spec["high"], int):
            params[name] = trial.suggest_int(
                name,
                spec["low"],
                spec["high"],
                step=spec.get("step", 1),
                log=spec.get("log", False),
            )
        else:
            params[name] = trial.suggest_float(
                name, float(spec["low"]), float(spec["high"]), log=spec.get("log", False)
            )
    return params


def objective_overrides(params: Mapping[str, Any]) -> list[str]:
    """``key=value`` overrides of a trial's values (lists as written: ``[64, 64]``)."""
    return [f"{name}={_override_value(value)}" for name, value in params.items()]


def _override_value(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return repr(value)
    return str(value)


def curve_score(returns: Sequence[float], expected: int) -> float:
    """Mean greedy return over ``expected`` evaluations, the last one held after an early stop.

    A run that stops when solved has fewer evaluations than its budget; its last (solved) value
    stands for the rest, so solving early scores higher than solving late.
    """
    if not returns:
        return -math.inf
    held = max(expected - len(returns), 0)
    return (sum(returns) + held * returns[-1]) / (len(returns) + held)


def frames_score(frames_to_solve: int | None, total_frames: int) -> float:
    """Frames to solve; a run that never solved counts as twice its frame budget."""
    return float(2 * total_frames if frames_to_solve is None else frames_to_solve)


def seconds_score(seconds_to_solve: float | None, train_seconds: float) -> float:
    """Training seconds to solve; a run that never solved counts as twice its training seconds."""
    return float(2 * train_seconds if seconds_to_solve is None else seconds_to_solve)


def write_preset(
    path: str | Path,
    base: Mapping[str, Any],
    params: Mapping[str, Any],
    header: Sequence[str],
    switch_defaults: Mapping[str, Any] | None = None,
) -> Path:
    """Write ``base`` (a preset's nested dict) with ``params`` (dotted keys) as a Hydra preset.

    ``header`` lines become its leading comments (``train.py --help`` shows the first). A tuned
    key of ``switch_defaults`` (:func:`variant_switch_defaults`: what the variant presets
    switch, at its default value) whose value is that default is left out, ``base``'s line for
    it too: env presets apply after algo presets, so writing it would switch the variant back
    (``env=<this> algo=double`` without double DQN).
    """
    merged = OmegaConf.merge(
        OmegaConf.create(dict(base)), OmegaConf.from_dotlist(objective_overrides(params))
    )
    switch_defaults = switch_defaults or {}
    for key, value in params.items():
        if key in switch_defaults and value == switch_defaults[key]:
            _drop(merged, key)
    text = "".join(f"# {line}\n" for line in header)
    text = "# @package _global_\n" + text + OmegaConf.to_yaml(merged)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _drop(tree: Any, dotted: str) -> None:
    """Remove ``dotted`` from the nested config ``tree``, and the sections it leaves empty."""
    *sections, leaf = dotted.split(".")
    nodes = [tree]
    for section in sections:
        nodes.append(nodes[-1][section])
    del nodes[-1][leaf]
    for node, section in zip(reversed(nodes[:-1]), reversed(sections), strict=True):
        if len(node[section]) == 0:
            del node[section]


def variant_switch_defaults(config_dir: str | Path) -> dict[str, Any]:
    """The keys the variant presets of ``config_dir/algo`` set, each at its value in the
    default config: the keys a tuned env preset must not repeat.

    A variant preset (double, dueling, noisy, c51, rainbow...) switches parts of the algorithm;
    one that sets the optimizer (``dqn``, ``tutorial``) is a whole recipe, not a variant.
    """
    from trl_cartpole.config.compose import compose_config

    default = compose_config(config_dir, [])
    keys: set[str] = set()
    for path in sorted((Path(config_dir) / "algo").glob("*.yaml")):
        preset = OmegaConf.to_container(OmegaConf.load(path))
        if "optim" not in preset:
            keys |= set(flat_fields(preset))
    keys.discard("algo.name")
    return {key: OmegaConf.select(default, key) for key in sorted(keys)}


def trial_score(
    config_dir: str | Path,
    overrides: Sequence[str],
    params: Mapping[str, Any],
    seeds: Sequence[int],
    trial_dir: Path,
    report: Any = None,
    objective: str = "return",
) -> float:
    """Train one run per seed with ``params``; the mean of their scores under ``objective``.

    ``report(step, value)`` (``optuna.Trial.report`` and a prune check) gets each evaluation's
    running score, the mean over this seed and the seeds before it; seed ``k``'s evaluations are
    steps ``k * total_frames + frames``. Under ``frames`` a seed's running score is its frames so
    far until it solves, and once it solves its frames to solve are reported at the remaining
    evaluation steps of its budget too, so that a trial still unsolved where most earlier trials
    had solved is pruned.
    """
    from trl_cartpole.config.compose import compose_config
    from trl_cartpole.run.training import train

    score_run = {
        "return": run_return_score,
        "frames": run_frames_score,
        "seconds": run_seconds_score,
    }[objective]
    scores: list[float] = []
    for index, seed in enumerate(seeds):
        run_overrides = [
            *overrides,
            *objective_overrides(params),
            f"seed={seed}",
            f"run_dir={trial_dir / f'seed{seed}'}",
            *QUIET_RUN,
        ]
        cfg = compose_config(config_dir, run_overrides)
        report_seed = seed_reporter(report, index * cfg.collector.total_frames, list(scores))
        scores.append(score_run(train, cfg, report_seed))
    return sum(scores) / len(scores)


def seed_reporter(report: Any, first_step: int, done: list[float]) -> Any:
    """``report_seed(frames, value)``: the mean of ``done`` and ``value`` at the seed's step."""

    def report_seed(frames: int, value: float) -> None:
        if report is not None:
            report(first_step + frames, (sum(done) + value) / (len(done) + 1))

    return report_seed


def run_return_score(train: Any, cfg: Any, report_seed: Any) -> float:
    """One run's :func:`curve_score`; each evaluation's running score reported at its frames."""
    expected = max(cfg.collector.total_frames // cfg.eval.interval_frames, 1)
    returns: list[float] = []

    def on_evaluation(evaluation: Evaluation) -> None:
        returns.append(evaluation.result.mean)
        report_seed(evaluation.frames, curve_score(returns, len(returns)))

    summary = train(cfg, on_evaluation=on_evaluation)
    return curve_score(summary["eval_curve"]["returns"], expected)


def run_frames_score(train: Any, cfg: Any, report_seed: Any) -> float:
    """One run's :func:`frames_score`; its frames so far reported at each evaluation."""
    summary = _train_reporting_until_solved(train, cfg, report_seed, "frames")
    return frames_score(summary["frames_to_solve"], cfg.collector.total_frames)


def run_seconds_score(train: Any, cfg: Any, report_seed: Any) -> float:
    """One run's :func:`seconds_score`; its training seconds so far reported at each evaluation."""
    summary = _train_reporting_until_solved(train, cfg, report_seed, "seconds")
    return seconds_score(summary["seconds_to_solve"], summary["train_seconds"])


def _train_reporting_until_solved(train: Any, cfg: Any, report_seed: Any, measure: str) -> Any:
    """Train, reporting each evaluation's ``frames`` or ``seconds`` at its frames (the step).

    Once a run solves, its value is held at the steps its budget would still have evaluated.
    """
    total = cfg.collector.total_frames
    batch = cfg.collector.frames_per_batch
    period = -(-cfg.eval.interval_frames // batch) * batch  # evaluations fall on whole batches

    def on_evaluation(evaluation: Evaluation) -> None:
        value = float(getattr(evaluation, measure))
        report_seed(evaluation.frames, value)
        if evaluation.solved:
            for frames in range(evaluation.frames + period, total + batch, period):
                report_seed(frames, value)

    return train(cfg, on_evaluation=on_evaluation)


# A trial's runs write no plots, periodic checkpoints or policies: only what the score needs.
QUIET_RUN = (
    "logger.progress_bar=false",
    "logger.live_plot=false",
    "logger.plots=false",
    "logger.backend=none",
    "checkpoint.interval_frames=0",
    "checkpoint.save_last=false",
    "checkpoint.save_best=false",
)
