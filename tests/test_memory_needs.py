"""What a run will hold in memory, known up front (trl_cartpole.run.memory_needs)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from trl_cartpole.config.schema import Config
from trl_cartpole.errors import ConfigError
from trl_cartpole.run.from_config import build_env
from trl_cartpole.run.memory_needs import MemoryNeed, available_memory_bytes, check_fits_in_memory
from trl_cartpole.run.progress import resident_mb
from trl_cartpole.run.resources import run_memory_need


def test_the_default_runs_need_is_counted_by_hand():
    cfg = Config()
    env = build_env(cfg, seed=0, num_envs=1)
    need = run_memory_need(cfg, env)
    # One step as TorchRL's fake step holds it: the action one-hot 2 x int64 = 16 bytes, the
    # observation 4 x float32 = 16, step_count 8, done/terminated/truncated 3 x 1 bool,
    # episode_reward 4; under "next": observation 16, reward 4, episode_reward 4, step_count 8
    # and the three flags 3.
    assert need.transition_bytes == 16 + 16 + 8 + 3 + 4 + (16 + 4 + 4 + 8 + 3)
    # MLP 4 -> 128 -> 128 -> 2, weights and biases
    assert need.parameters == (4 * 128 + 128) + (128 * 128 + 128) + (128 * 2 + 2)
    assert need.copies_per_parameter == 6  # AMSGrad: weights, target, gradient, 3 Adam states
    assert need.total_bytes == 50_000 * 82 + 17_410 * 4 * 6
    env.close()


def test_counting_allocates_nothing_and_draws_no_random_number():
    cfg = Config()
    cfg.network.noisy, cfg.network.distributional = True, True  # noise drawn at construction
    env = build_env(cfg, seed=0, num_envs=1)
    cfg.network.num_cells = [1 << 20, 1 << 20]  # 4 TiB of float32 weights if allocated
    before = torch.random.get_rng_state()
    need = run_memory_need(cfg, env)
    assert torch.equal(torch.random.get_rng_state(), before)  # the run's first draws unchanged
    assert need.parameters > 2**40
    env.close()


def test_a_need_beyond_what_is_available_is_one_line_naming_both_and_the_fix():
    need = MemoryNeed(
        transitions=10**9, transition_bytes=100, parameters=1000, copies_per_parameter=6
    )
    check_fits_in_memory(need, available=need.total_bytes)  # exactly fits
    check_fits_in_memory(need, available=None)  # no /proc/meminfo: nothing to compare
    with pytest.raises(ConfigError) as refused:
        check_fits_in_memory(need, available=need.total_bytes - 1)
    message = str(refused.value)
    assert "\n" not in message and "93.1 GiB" in message and "lower buffer.max_size" in message


def test_available_memory_is_read_from_meminfo(tmp_path):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       1000 kB\nMemAvailable:    512 kB\n")
    assert available_memory_bytes(meminfo) == 512 * 1024
    assert available_memory_bytes(tmp_path / "absent") is None


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads Linux's /proc")
def test_resident_memory_counts_the_processes_the_run_started():
    """A collector worker's memory is the run's too: a child holding 200 MiB shows in it."""
    before = resident_mb()
    child = subprocess.Popen(
        [sys.executable, "-c", "import sys; b = bytearray(200 * 2**20); sys.stdin.read()"],
        stdin=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 60
        while resident_mb() - before < 200 and time.monotonic() < deadline:
            time.sleep(0.05)  # until the child has touched its 200 MiB
        assert resident_mb() - before >= 200
    finally:
        child.communicate(b"")
    assert resident_mb() - before < 50  # an ended worker no longer counts
