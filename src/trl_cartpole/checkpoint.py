"""Checkpoints through ``torchrl.checkpoint.Checkpoint``: the best policy and the training state.

``Checkpoint.save`` stages every file under a temporary name and renames the directory into
place, so an interrupted (or killed) save leaves the previous checkpoint intact. Periodic
training states rotate through ``CheckpointRotation`` (the newest ``keep_last`` are kept).
:class:`Checkpointer` decides when the training loop saves: every
``checkpoint.interval_frames`` frames and on a stop signal.

Resuming: :func:`find_resume_checkpoint` turns ``resume=PATH`` (a run directory or a
training-state checkpoint) into a checkpoint, :func:`resume_config` rebuilds the run's config
from it (only a few fields may change), and :func:`load_training_state` restores every
component in place. Anything wrong raises a one-line :class:`ConfigError`.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import signal
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import OmegaConf
from tensordict import is_tensor_collection
from torch import nn
from torchrl.checkpoint import Checkpoint, CheckpointError, CheckpointRotation, GlobalRNGState

from trl_cartpole.config import Config, flat_fields, to_config
from trl_cartpole.console import command, shown_path
from trl_cartpole.errors import ConfigError, DiskFull, TrainingInterrupted, WorkerLost
from trl_cartpole.files import free_bytes, megabytes, tree_bytes, write_json_atomic
from trl_cartpole.pickle_scan import no_unpickling, refuse_code
from trl_cartpole.progress import Progress
from trl_cartpole.validation import check_boolean_overrides, validate

__all__ = [
    "RESUMABLE_FIELDS",
    "Checkpointer",
    "find_resume_checkpoint",
    "load_policy",
    "load_training_state",
    "read_checkpoint_config",
    "read_observation_norm",
    "resume_config",
    "run_dir_of",
    "save_policy",
    "save_training_state",
    "state_bytes",
    "verify_checkpoint",
]

POLICY, TRAINING_STATE = "policy", "training_state"  # the two kinds of checkpoint
INTEGRITY = "integrity.json"  # SHA-256 of every file, written once the checkpoint is complete
TRUST_PICKLE = "checkpoint.trust_pickled_envs"
# What a resumed run may change; everything else must match the stored config.
RESUMABLE_FIELDS = (
    "collector.total_frames",
    "checkpoint.interval_frames",
    "run_dir",
    "checkpoint.keep_last",
    "logger.progress_bar",
    "logger.verbose",
    "logger.live_plot",
    "logger.live_plot_seconds",
    "logger.plots",
    "collector.ray_address",  # a restarted cluster may listen elsewhere
    "collector.ray_resources",  # ... and name its nodes otherwise
    "collector.ray_runtime_env",
    TRUST_PICKLE,  # read from the resuming command only, never from the checkpoint
)


# The layout of a training state's components; a state of another format is refused in one line
# (format 2: the loop's history under "history"; no state of format 1 is read any more).
TRAINING_STATE_FORMAT = 2

# Room asked for beyond a checkpoint's expected size before it is written (file-system blocks,
# the manifest, the integrity record): a full disk would otherwise end the run mid-write, where
# the memory-mapped tensors of the replay buffer die of SIGBUS instead of raising ENOSPC.
DISK_MARGIN_FRACTION, DISK_MARGIN_BYTES = 0.1, 1_000_000


def state_bytes(state: Any) -> int:
    """The bytes of the tensors and arrays in a (nested) state dict: what a checkpoint stores."""
    if isinstance(state, torch.Tensor):
        return state.numel() * state.element_size()
    if is_tensor_collection(state):
        return state.bytes()
    if isinstance(state, np.ndarray):
        return state.nbytes
    if isinstance(state, Mapping):
        return sum(state_bytes(value) for value in state.values())
    if isinstance(state, (list, tuple)):
        return sum(state_bytes(value) for value in state)
    return 0


def _config_metadata(cfg: Config, kind: str, **extra: Any) -> dict[str, Any]:
    config = OmegaConf.to_container(OmegaConf.structured(cfg), resolve=True)
    return {"kind": kind, "config": config, **extra}


def check_training_state_format(path: str | Path) -> None:
    """Raise a one-line :class:`ConfigError` unless ``path`` has this version's state format."""
    found = Checkpoint.manifest(path).get("metadata", {}).get("format", 1)
    if found != TRAINING_STATE_FORMAT:
        raise ConfigError(
            f"resume={str(path)!r} is a training state of format {found}, and this version "
            f"reads format {TRAINING_STATE_FORMAT}; resume it with the version that wrote it, or "
            "start a new run (its best policy still evaluates and exports)"
        )


def save_policy(path: str | Path, actor: nn.Module, cfg: Config, **metadata: Any) -> Path:
    """Save the Q-actor's weights with the config that rebuilds it.

    ``metadata`` goes to the manifest; ``observation_norm`` there holds the run's
    observation statistics (:func:`read_observation_norm`).
    """
    saved = Checkpoint(policy=actor).save(path, metadata=_config_metadata(cfg, POLICY, **metadata))
    return _write_integrity(Path(saved))


def save_training_state(
    path: str | Path,
    cfg: Config,
    counters: dict[str, Any],
    keep_last: int | None = None,
    observation_norm: dict[str, list[float]] | None = None,
    **components: Any,
) -> Path:
    """Save every component (modules, optimizer, buffer, collector...) plus RNGs and counters.

    With ``keep_last``, ``path`` is a directory of rotated checkpoints (``CheckpointRotation``)
    of which the newest ``keep_last`` are kept; otherwise ``path`` is the checkpoint itself.
    ``observation_norm`` (the run's observation statistics) goes to the manifest.
    """
    checkpoint = Checkpoint(rng=GlobalRNGState(), **components)
    metadata = _config_metadata(
        cfg,
        TRAINING_STATE,
        format=TRAINING_STATE_FORMAT,
        counters=counters,
        observation_norm=observation_norm,
    )
    if keep_last is None:
        return _write_integrity(Path(checkpoint.save(path, metadata=metadata)))
    rotation = CheckpointRotation(path, keep_last=keep_last)
    return _write_integrity(
        Path(rotation.save(checkpoint, step=counters["frames"], metadata=metadata))
    )


def load_training_state(path: str | Path, **components: Any) -> dict[str, Any]:
    """Load every component saved by :func:`save_training_state` in place; return the metadata."""
    verify_checkpoint(path)
    try:
        with no_unpickling(path):
            Checkpoint(rng=GlobalRNGState(), **components).load(path)
        return Checkpoint.manifest(path)["metadata"]
    except ConfigError:
        raise
    except Exception as error:  # torch, pickle, zip and JSON errors of a damaged checkpoint
        first_line = (str(error).splitlines() or [type(error).__name__])[0]
        raise ConfigError(
            f"resume={str(path)!r} cannot be loaded ({first_line}); it is damaged or was not "
            "written by this run's version"
        ) from None


def find_resume_checkpoint(path: str | Path) -> Path:
    """The training state to resume from ``path``: a run directory or a checkpoint in one.

    In a run directory that is the one with the most frames among the newest complete periodic
    checkpoint (``checkpoints/periodic``) and the end-of-run state (``checkpoints/last``). A
    periodic checkpoint without its integrity record was cut off while being written and is
    passed over; one whose files do not match their record raises :class:`ConfigError`.
    """
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"resume={str(path)!r} does not exist; pass a run directory")
    if (path / "manifest.json").is_file():
        verify_checkpoint(path)
        return path
    candidates = find_complete_checkpoints(path)
    if not candidates:
        raise ConfigError(
            f"resume={str(path)!r} holds no complete training state (checkpoints/periodic or "
            "checkpoints/last); pass the run directory of a run with checkpoints"
        )
    for candidate in candidates:
        verify_checkpoint(candidate)
    return max(candidates, key=lambda c: _read_manifest(c)["metadata"]["counters"]["frames"])


def find_complete_checkpoints(run_dir: str | Path) -> list[Path]:
    """The newest complete periodic training state of ``run_dir`` and its end-of-run one, of
    those that exist (complete: with the integrity record written after every other file)."""
    candidates = []
    periodic = Path(run_dir) / "checkpoints" / "periodic"
    entries = sorted(periodic.iterdir(), reverse=True) if periodic.is_dir() else []
    for entry in entries:
        if entry.is_dir() and not entry.name.startswith(".") and (entry / INTEGRITY).is_file():
            candidates.append(entry)
            break
    last = Path(run_dir) / "checkpoints" / "last"
    if (last / INTEGRITY).is_file():
        candidates.append(last)
    return candidates


def _read_manifest(path: Path) -> dict[str, Any]:
    try:
        return Checkpoint.manifest(path)
    except (CheckpointError, OSError, ValueError) as error:
        raise ConfigError(
            f"checkpoint={str(path)!r} is not a trl_cartpole checkpoint ({error})"
        ) from None


def _file_digests(path: Path) -> dict[str, str]:
    return {
        str(file.relative_to(path)): hashlib.sha256(file.read_bytes()).hexdigest()
        for file in sorted(path.rglob("*"))
        if file.is_file() and file.name != INTEGRITY
    }


def _write_integrity(path: Path) -> Path:
    """Record a SHA-256 of every file of the checkpoint at ``path`` (written atomically)."""
    write_json_atomic(path / INTEGRITY, _file_digests(path))
    return path


def verify_checkpoint(path: str | Path) -> None:
    """Raise :class:`ConfigError` unless every file of the checkpoint matches its record.

    Then refuse a checkpoint holding a pickle that could run code
    (:func:`trl_cartpole.pickle_scan.refuse_code`): nothing is loaded from it.
    """
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"checkpoint={str(path)!r} does not exist; pass a checkpoint directory")
    record = path / INTEGRITY
    if not record.is_file():
        raise ConfigError(
            f"checkpoint={str(path)!r} has no {INTEGRITY}: it was cut off while being written "
            "or is not a trl_cartpole checkpoint"
        )
    try:
        expected = json.loads(record.read_text())
    except ValueError:
        raise ConfigError(f"checkpoint={str(path)!r} has a corrupt {INTEGRITY}") from None
    found = _file_digests(path)
    damaged = sorted(name for name in expected if found.get(name) != expected[name])
    if damaged:
        raise ConfigError(
            f"checkpoint={str(path)!r} is damaged: {', '.join(damaged[:3])}"
            f"{' ...' if len(damaged) > 3 else ''} missing, truncated or changed since it was "
            "written; use an older checkpoint"
        )
    refuse_code(path)


def run_dir_of(checkpoint: str | Path) -> Path:
    """The run directory a checkpoint belongs to (the nearest parent with ``config.yaml``)."""
    for parent in Path(checkpoint).resolve().parents:
        if (parent / "config.yaml").is_file() and (parent / "checkpoints").is_dir():
            return parent
    raise ConfigError(f"resume={str(checkpoint)!r} is not inside a run directory")


def resume_config(checkpoint: str | Path, overrides: Sequence[str] = ()) -> Config:
    """The stored config of a training-state checkpoint with ``overrides`` applied.

    Only :data:`RESUMABLE_FIELDS` may differ from the stored run; any other override, or a
    policy checkpoint (which holds no training state), raises :class:`ConfigError`.
    """
    kind = Checkpoint.manifest(checkpoint).get("metadata", {}).get("kind")
    if kind != TRAINING_STATE:
        raise ConfigError(
            f"resume={str(checkpoint)!r} is a {kind or 'foreign'} checkpoint without training "
            "state; pass the run directory (its checkpoints/periodic or checkpoints/last)"
        )
    check_training_state_format(checkpoint)
    stored = read_checkpoint_config(checkpoint)
    # Trust in pickled env state comes from whoever resumes, not from the checkpoint's config.
    stored.checkpoint.trust_pickled_envs = False
    check_boolean_overrides(overrides)
    merged = OmegaConf.merge(OmegaConf.structured(stored), OmegaConf.from_dotlist(list(overrides)))
    cfg = validate(to_config(merged))
    before, after = flat_fields(stored), flat_fields(cfg)
    changed = sorted(key for key in after if after[key] != before.get(key))
    refused = [key for key in changed if key not in RESUMABLE_FIELDS]
    if refused:
        raise ConfigError(
            f"resume continues the stored run, so {', '.join(refused)} cannot change; only "
            f"{', '.join(RESUMABLE_FIELDS)} may"
        )
    frames = Checkpoint.manifest(checkpoint)["metadata"]["counters"]["frames"]
    if cfg.collector.total_frames <= frames:
        raise ConfigError(
            f"collector.total_frames={cfg.collector.total_frames} leaves nothing to train: the "
            f"run has {frames} frames; pass a larger collector.total_frames to continue it"
        )
    return cfg


def read_checkpoint_config(path: str | Path) -> Config:
    """Return the config stored in a checkpoint's manifest, or raise a one-line ConfigError."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"checkpoint={str(path)!r} does not exist; pass a checkpoint directory")
    try:
        manifest = Checkpoint.manifest(path)
        return to_config(manifest["metadata"]["config"])
    except (CheckpointError, KeyError, TypeError, ValueError, OSError) as error:
        raise ConfigError(
            f"checkpoint={str(path)!r} is not a trl_cartpole checkpoint ({error})"
        ) from None


def read_observation_norm(path: str | Path) -> dict[str, list[float]] | None:
    """The observation statistics a checkpoint's run normalised with (None: it did not)."""
    return Checkpoint.manifest(path)["metadata"].get("observation_norm")


def load_policy(path: str | Path, actor: nn.Module) -> nn.Module:
    """Load policy weights saved by :func:`save_policy` into ``actor`` (in place)."""
    verify_checkpoint(path)
    try:
        with no_unpickling(path):
            Checkpoint(policy=actor).load(path, components=["policy"])
    except (CheckpointError, RuntimeError, KeyError) as error:
        first_line = str(error).splitlines()[0]
        raise ConfigError(
            f"checkpoint={str(path)!r} does not fit this policy ({first_line})"
        ) from None
    return actor


class Checkpointer:
    """Saves the training state: periodically, on a stop signal, and at the end of the run.

    ``components`` maps checkpoint names to objects with ``state_dict``/``load_state_dict``
    (TorchRL modules, the optimizer, the replay buffer, the collector, the loop's own state);
    they are saved together with the global RNG states, and loaded in their order.
    """

    def __init__(
        self,
        run_dir: Path,
        cfg: Config,
        components: Mapping[str, Any],
        observation_norm: dict[str, list[float]] | None = None,
        metrics: Any = None,
    ) -> None:
        self.run_dir, self.cfg = run_dir, cfg
        self.components = dict(components)
        self.observation_norm = observation_norm
        self.metrics = metrics  # a MetricsLog: its W&B step goes into the counters
        self.interval = cfg.checkpoint.interval_frames or math.inf
        self.last_saved_frame = 0
        self.state_size: int | None = None  # bytes of the last training state written

    def load(self, path: str | Path, progress: Progress) -> None:
        """Restore every component from the training state at ``path``."""
        check_training_state_format(path)
        components = dict(self.components)
        if "replay_buffer" not in Checkpoint.manifest(path)["components"]:
            components.pop("replay_buffer", None)  # saved while an n-step buffer was empty
        load_training_state(path, **components)
        self.last_saved_frame = progress.frames

    def save(self, path: Path, progress: Progress, keep_last: int | None = None) -> Path:
        counters = {"frames": progress.frames, "updates": progress.updates}
        logger_step = None if self.metrics is None else self.metrics.logger_step()
        if logger_step is not None:
            counters["logger_step"] = logger_step  # a W&B resume rewinds to it
        buffer = self.components.get("replay_buffer")
        # An n-step buffer may still be empty (its windows are not complete yet): nothing to save.
        components = {
            name: component
            for name, component in self.components.items()
            if name != "replay_buffer" or len(buffer) > 0
        }
        # The replay buffer's storage is allocated whole with its first batch, so a training
        # state is about as large as the one before it; the first is estimated from its tensors.
        expected = self.state_size or sum(
            state_bytes(component.state_dict()) for component in components.values()
        )
        saved = self._write_or_stop(
            path,
            expected,
            lambda: save_training_state(
                path,
                self.cfg,
                counters,
                keep_last,
                observation_norm=self.observation_norm,
                **components,
            ),
        )
        self.state_size = tree_bytes(saved)
        return saved

    def _write_or_stop(self, path: Path, expected: int, write: Callable[[], Path]) -> Path:
        """``write()`` a checkpoint of about ``expected`` bytes at ``path``, or raise
        :class:`DiskFull` if it cannot fit: before the write when the free space is short,
        after it when the write fails with ENOSPC (TorchRL's staged files are then removed)."""
        needed = int(expected * (1 + DISK_MARGIN_FRACTION)) + DISK_MARGIN_BYTES
        if free_bytes(path) < needed:
            raise self._disk_full(path, needed)
        try:
            return write()
        except OSError as error:
            if error.errno != errno.ENOSPC:
                raise
            raise self._disk_full(path, needed) from None

    def _disk_full(self, path: Path, needed: int) -> DiskFull:
        free = free_bytes(path)
        if find_complete_checkpoints(self.run_dir):
            then = f"then resume with: {self.resume_command()}"
        else:
            then = "then start the run again (no training state was written before this one)"
        if free >= needed:  # the write failed all the same: something else fills the disk
            return DiskFull(
                f"no space left for the checkpoint at {shown_path(path)}: the write failed with "
                f"ENOSPC though {megabytes(free)} is free now (another writer on that disk?); "
                f"make room, {then}"
            )
        return DiskFull(
            f"no space left for the checkpoint at {shown_path(path)}: it needs about "
            f"{megabytes(needed)} and {megabytes(free)} is free; free "
            f"{megabytes(needed - free)} or more on that disk, {then}"
        )

    def maybe_save(self, progress: Progress, stop: Any) -> None:
        """Save a periodic state when one is due or a stop signal came (then stop the run).

        ``stop`` is the :class:`~trl_cartpole.run_control.StopRequest` of the loop. After a
        signal, the state is saved and :class:`TrainingInterrupted` raised.
        """
        due = progress.frames - self.last_saved_frame >= self.interval
        if not (due or stop.requested):
            return
        self._save_periodic(progress)
        if stop.requested:
            raise TrainingInterrupted(
                f"stopped by {signal.Signals(stop.signum).name} at frame {progress.frames}; "
                f"checkpoint written; resume with: {self.resume_command()}",
                stop.signum,
            )
        progress.clock.start()

    def stop_for_lost_worker(self, progress: Progress, lost: str) -> WorkerLost:
        """Save a periodic state of the batches trained so far; return the error that ends the
        run, naming the ``lost`` worker and the resume command."""
        self._save_periodic(progress)
        return WorkerLost(
            f"{lost}; the run stopped at frame {progress.frames} with a checkpoint; resume with: "
            f"{self.resume_command()}"
        )

    def _save_periodic(self, progress: Progress) -> None:
        """Stop the training clock and save a state under ``checkpoints/periodic``."""
        progress.clock.pause()
        self.save(
            self.run_dir / "checkpoints" / "periodic", progress, self.cfg.checkpoint.keep_last
        )
        self.last_saved_frame = progress.frames

    def resume_command(self) -> str:
        """The command that continues this run from its newest checkpoint."""
        return f"{command('train')} resume={shown_path(self.run_dir)}"

    def save_best(self, policy: nn.Module, frames: int, eval_return_mean: float) -> None:
        """The best policy so far (``checkpoints/best``), if ``checkpoint.save_best``."""
        if self.cfg.checkpoint.save_best:
            path = self.run_dir / "checkpoints" / "best"
            self._write_or_stop(
                path,
                state_bytes(policy.state_dict()),
                lambda: save_policy(
                    path,
                    policy,
                    self.cfg,
                    frames=frames,
                    eval_return_mean=eval_return_mean,
                    observation_norm=self.observation_norm,
                ),
            )

    def save_last(self, progress: Progress) -> None:
        """The end-of-run state (``checkpoints/last``), if ``checkpoint.save_last``."""
        if self.cfg.checkpoint.save_last:
            self.save(self.run_dir / "checkpoints" / "last", progress)
