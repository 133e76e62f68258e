"""buffer.storage=memmap: TorchRL's LazyMemmapStorage, files in the run directory."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import LazyMemmapStorage

from tests.conftest import SMOKE_OVERRIDES, TIMING_KEYS, run_script_in_process
from trl_cartpole.config.schema import Config, to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.errors import ConfigError
from trl_cartpole.run.from_config import REPLAY_FILES, build_replay_buffer
from trl_cartpole.run.memory_needs import (
    MemoryNeed,
    check_buffer_fits_on_disk,
    check_fits_in_memory,
)

RUN = [*SMOKE_OVERRIDES, "checkpoint.interval_frames=100", "seed=3"]


def _summary(run_dir) -> dict:
    """summary.json without what differs between two runs of one config (timings, memory)."""
    summary = json.loads((run_dir / "summary.json").read_text())
    del summary["eval_curve"]["seconds"], summary["eval_curve"]["rss_mb"]
    return {key: value for key, value in summary.items() if key not in TIMING_KEYS}


@pytest.mark.slow  # two runs
def test_the_buffer_in_files_learns_what_the_buffer_in_memory_learns(tmp_path):
    in_memory, in_files = tmp_path / "memory", tmp_path / "memmap"
    assert run_script_in_process("train.py", *RUN, f"run_dir={in_memory}").returncode == 0
    proc = run_script_in_process("train.py", *RUN, f"run_dir={in_files}", "buffer.storage=memmap")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert _summary(in_files) == _summary(in_memory)  # same transitions, same samples
    assert not (in_files / REPLAY_FILES).exists()  # removed once the last state holds them
    # The training state holds the buffer: a resume reads it into new files and trains on.
    more = run_script_in_process("train.py", f"resume={in_files}", "collector.total_frames=400")
    assert more.returncode == 0, more.stderr[-2000:]
    assert json.loads((in_files / "summary.json").read_text())["frames"] == 400


def test_build_replay_buffer_keeps_memmap_files_in_the_run_directory(tmp_path):
    cfg = Config()
    cfg.buffer.storage, cfg.buffer.max_size, cfg.buffer.n_steps = "memmap", 100, 1
    buffer = build_replay_buffer(cfg, tmp_path)
    assert isinstance(buffer.storage, LazyMemmapStorage)
    buffer.extend(TensorDict({"pixels": torch.ones(10, 2, 3, dtype=torch.uint8)}, [10]))
    files = tmp_path / REPLAY_FILES
    assert (files / "pixels.memmap").is_file()
    # the file has room for 100 transitions of 2 x 3 bytes
    assert (files / "pixels.memmap").stat().st_size == 100 * 2 * 3
    # a stopped run's files are written over, not refused
    again = build_replay_buffer(cfg, tmp_path)
    again.extend(TensorDict({"pixels": torch.zeros(10, 2, 3, dtype=torch.uint8)}, [10]))
    assert len(again) == 10


def test_a_buffer_in_files_is_checked_against_the_disk_not_the_memory(tmp_path):
    need = MemoryNeed(
        transitions=1000, transition_bytes=1000, parameters=10, copies_per_parameter=6
    )
    # 1 MB of buffer, 240 bytes of networks: 100 kB of memory is enough without the buffer
    check_fits_in_memory(need, 100_000, buffer_in_memory=False)
    with pytest.raises(ConfigError, match=r"set buffer\.storage=memmap"):
        check_fits_in_memory(need, 100_000)
    with pytest.raises(
        ConfigError, match=r"buffer\.storage=memmap needs 0\.0 GiB .* is free there"
    ):
        check_buffer_fits_on_disk(need, tmp_path / REPLAY_FILES, free=999_999)
    check_buffer_fits_on_disk(need, tmp_path / REPLAY_FILES, free=1_000_000)
    # what a stopped run's files already take counts as held
    (tmp_path / REPLAY_FILES).mkdir()
    (tmp_path / REPLAY_FILES / "pixels.memmap").write_bytes(b"x" * 8192)
    check_buffer_fits_on_disk(need, tmp_path / REPLAY_FILES, free=1_000_000 - 8192)


def test_a_memmap_buffer_larger_than_the_disk_is_refused_before_the_run(tmp_path):
    run_dir = tmp_path / "run"
    proc = run_script_in_process(
        "train.py",
        *RUN,
        f"run_dir={run_dir}",
        "buffer.storage=memmap",
        "buffer.max_size=1000000000000000",
    )
    assert proc.returncode == 2
    line = proc.stderr.strip()
    assert line.startswith("error: buffer.storage=memmap needs") and "\n" not in line
    assert not run_dir.exists()


def _transitions(count: int, start: int = 0) -> TensorDict:
    value = torch.arange(start, start + count, dtype=torch.float32)[:, None]  # [count, 1]
    return TensorDict(
        {
            "observation": value.expand(count, 4).clone(),
            "action": torch.zeros(count, 2),
            ("next", "observation"): value.expand(count, 4) + 1,
            ("next", "reward"): torch.ones(count, 1),
            ("next", "done"): torch.zeros(count, 1, dtype=torch.bool),
            ("next", "terminated"): torch.zeros(count, 1, dtype=torch.bool),
        },
        [count],
    )


def _bytes_under(path: Path) -> int:
    return sum(file.stat().st_size for file in path.rglob("*") if file.is_file())


@pytest.mark.parametrize("loaded_into", ["a fresh buffer", "a filled buffer"])
def test_a_buffers_checkpoint_holds_its_transitions_not_its_capacity(
    compose, tmp_path, loaded_into
):
    cfg = validate(to_config(compose("buffer.max_size=20000", "buffer.n_steps=1")))
    buffer = build_replay_buffer(cfg)
    buffer.extend(_transitions(100))
    buffer.dumps(tmp_path / "saved")
    row = 4 * 4 * 2 + 2 * 4 + 4 + 2  # bytes of one transition: observations, action, flags
    assert _bytes_under(tmp_path / "saved") < 100 * row + 200_000  # not 20 000 rows (~1 MB)

    resumed = build_replay_buffer(cfg)
    if loaded_into == "a filled buffer":  # its storage allocated: loaded in place
        resumed.extend(_transitions(300, start=1000))
    resumed.loads(tmp_path / "saved")
    assert len(resumed) == 100 and resumed.storage.max_size == 20000
    stored = resumed.storage.get(torch.arange(100))
    assert torch.equal(stored["observation"][:, 0], torch.arange(100.0))
    resumed.extend(_transitions(5, start=500))  # the writer goes on at row 100
    assert len(resumed) == 105
    assert torch.equal(
        resumed.storage.get(torch.arange(100, 105))["observation"][:, 0], torch.arange(500.0, 505.0)
    )
