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

import dataclasses
import hashlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException
from tensordict import is_tensor_collection
from torch import nn
from torchrl.checkpoint import Checkpoint, CheckpointError, CheckpointRotation, GlobalRNGState

from trl_cartpole.config.schema import Config, flat_fields, to_config
from trl_cartpole.config.validation import check_boolean_overrides, validate
from trl_cartpole.errors import ConfigError
from trl_cartpole.store.files import write_json_atomic
from trl_cartpole.store.pickle_scan import no_unpickling, refuse_code

__all__ = [
    "RESUMABLE_FIELDS",
    "find_resume_checkpoint",
    "load_policy",
    "load_training_state",
    "newest_policy",
    "read_checkpoint_config",
    "read_observation_norm",
    "resume_config",
    "run_dir_of",
    "save_policy",
    "save_training_state",
    "state_bytes",
    "verify_checkpoint",
    "write_integrity",
]

POLICY, TRAINING_STATE = "policy", "training_state"  # the two kinds of checkpoint
INTEGRITY = "integrity.json"  # SHA-256 of every file, written once the checkpoint is complete
TRUST_PICKLE = "checkpoint.trust_pickled_envs"
# What a resumed run may change; everything else must match the stored config.
RESUMABLE_FIELDS = (
    "collector.total_frames",
    "collector.max_train_seconds",
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
# (format 6: the config's sections named by the factories' keywords, before the first release).
TRAINING_STATE_FORMAT = 6
READABLE_TRAINING_STATE_FORMATS = (6,)

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
    # The schema's fields are plain values, lists and nested dataclasses: ``asdict`` gives the
    # same tree as OmegaConf's ``to_container(structured(cfg))`` in 0.3 ms instead of about 29
    # (a run saves its config with every best policy and training state).
    return {"kind": kind, "config": dataclasses.asdict(cfg), **extra}


def check_training_state_format(path: str | Path) -> None:
    """Raise a one-line :class:`ConfigError` unless ``path`` has this version's state format."""
    found = Checkpoint.manifest(path).get("metadata", {}).get("format", 1)
    if found not in READABLE_TRAINING_STATE_FORMATS:
        readable = " and ".join(str(number) for number in READABLE_TRAINING_STATE_FORMATS)
        raise ConfigError(
            f"resume={str(path)!r} is a training state of format {found}, and this version "
            f"reads formats {readable}; resume it with the version that wrote it, or start a "
            "new run (its best policy still evaluates and exports)"
        )


def save_policy(path: str | Path, actor: nn.Module, cfg: Config, **metadata: Any) -> Path:
    """Save the Q-actor's weights with the config that rebuilds it.

    ``metadata`` goes to the manifest; ``observation_norm`` there holds the run's
    observation statistics (:func:`read_observation_norm`).
    """
    saved = Checkpoint(policy=actor).save(path, metadata=_config_metadata(cfg, POLICY, **metadata))
    return write_integrity(Path(saved))


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
        return write_integrity(Path(checkpoint.save(path, metadata=metadata)))
    rotation = CheckpointRotation(path, keep_last=keep_last)
    return write_integrity(
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
    checkpoint (``checkpoints/periodic``) and the end-of-run state (``checkpoints/last``), the
    end-of-run one on a tie. A
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
    # on a tie the end-of-run state (after the last evaluation), listed last: taken first
    return max(
        reversed(candidates), key=lambda c: _read_manifest(c)["metadata"]["counters"]["frames"]
    )


def newest_policy(run_dir: str | Path) -> Path | None:
    """The policy a run directory offers: its best policy (``checkpoints/best``), or before its
    first evaluation the one in the training state a resume would continue from
    (:func:`find_resume_checkpoint`); None if it has neither."""
    best = Path(run_dir) / "checkpoints" / "best"
    if (best / "manifest.json").is_file():
        return best
    return find_resume_checkpoint(run_dir) if find_complete_checkpoints(run_dir) else None


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


# The digests of the files of the checkpoints this process wrote, by file identity (device,
# inode, size, modification time): a file hard-linked into a later checkpoint (a replay
# buffer's unchanged rows, storage/chunked.py) is the same file, not read again. The
# oldest are dropped past DIGESTS_KEPT (a run's checkpoints hold a few hundred files each).
_written_digests: dict[tuple[int, int, int, int], str] = {}
DIGESTS_KEPT = 20_000


def _file_digests(path: Path, reuse: bool = False) -> dict[str, str]:
    """The SHA-256 of every file under ``path``; with ``reuse``, a file this process wrote
    into an earlier checkpoint (the same inode: a hard link) keeps the digest it had there."""
    digests = {}
    for file in sorted(path.rglob("*")):
        if not file.is_file() or file.name == INTEGRITY:
            continue
        stat = file.stat()
        identity = (stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns)
        # only a file with another name (a link): a new file may reuse a deleted one's inode
        digest = _written_digests.get(identity) if reuse and stat.st_nlink > 1 else None
        if digest is None:
            digest = hashlib.sha256(file.read_bytes()).hexdigest()
        if reuse:
            _written_digests.pop(identity, None)  # now the newest
            _written_digests[identity] = digest
        digests[str(file.relative_to(path))] = digest
    while len(_written_digests) > DIGESTS_KEPT:
        del _written_digests[next(iter(_written_digests))]
    return digests


def write_integrity(path: Path) -> Path:
    """Record a SHA-256 of every file of the checkpoint at ``path`` (written atomically)."""
    write_json_atomic(path / INTEGRITY, _file_digests(path, reuse=True))
    return path


def verify_checkpoint(path: str | Path) -> None:
    """Raise :class:`ConfigError` unless every file of the checkpoint matches its record.

    Then refuse a checkpoint holding a pickle that could run code
    (:func:`trl_cartpole.store.pickle_scan.refuse_code`): nothing is loaded from it.
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
    counters = Checkpoint.manifest(checkpoint)["metadata"]["counters"]
    frames, total = counters["frames"], cfg.collector.total_frames
    same_total = total == stored.collector.total_frames
    same_time = cfg.collector.max_train_seconds == stored.collector.max_train_seconds
    if same_total and same_time and _finished(checkpoint, frames):
        raise ConfigError(
            f"resume={str(checkpoint)!r} is a finished run (its summary.json is written); pass "
            f"a larger collector.total_frames than {total} (or collector.max_train_seconds) to "
            "train it on"
        )
    if total <= frames and not same_total:
        raise ConfigError(
            f"collector.total_frames={total} leaves nothing to train: the run has {frames} "
            "frames; pass a larger collector.total_frames to continue it, or none to finish it"
        )
    return cfg


def _finished(checkpoint: str | Path, frames: int) -> bool:
    """Whether the run of ``checkpoint`` wrote its ending at ``frames`` (a ``summary.json`` of
    those frames, not a failure's). A run stopped after its training but before that resumes
    straight to the ending (``train``)."""
    try:
        summary = json.loads((run_dir_of(checkpoint) / "summary.json").read_text())
    except (ConfigError, OSError, ValueError):  # none yet (or no run directory around it)
        return False
    return (
        isinstance(summary, dict) and summary.get("frames") == frames and not summary.get("failed")
    )


def read_checkpoint_config(path: str | Path) -> Config:
    """Return the config stored in a checkpoint's manifest, or raise a one-line ConfigError."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"checkpoint={str(path)!r} does not exist; pass a checkpoint directory")
    try:
        manifest = Checkpoint.manifest(path)
        stored = manifest["metadata"]["config"]
    except (CheckpointError, KeyError, TypeError, ValueError, OSError) as error:
        raise ConfigError(
            f"checkpoint={str(path)!r} is not a trl_cartpole checkpoint ({error})"
        ) from None
    try:
        return to_config(stored)
    except OmegaConfBaseException:  # a key the schema no longer has, or of another type
        raise ConfigError(
            f"checkpoint={str(path)!r} was saved by an earlier layout of trl_cartpole's config, "
            "which this version does not read; train it anew"
        ) from None


def read_observation_norm(path: str | Path) -> dict[str, list[float]] | None:
    """The observation statistics a checkpoint's run normalised with (None: it did not)."""
    return Checkpoint.manifest(path)["metadata"].get("observation_norm")


def load_policy(path: str | Path, actor: nn.Module) -> nn.Module:
    """Load policy weights saved by :func:`save_policy` into ``actor`` (in place), read onto
    ``actor``'s device whatever device they were saved from (a GPU run's, on a CPU machine)."""
    verify_checkpoint(path)
    device = next(actor.parameters()).device
    try:
        with no_unpickling(path):
            Checkpoint(policy=actor).load(path, components=["policy"], map_location=device)
    except (CheckpointError, RuntimeError, KeyError) as error:
        first_line = str(error).splitlines()[0]
        raise ConfigError(
            f"checkpoint={str(path)!r} does not fit this policy ({first_line})"
        ) from None
    return actor
