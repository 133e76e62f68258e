"""``device=cuda`` end to end: skipped on a machine without a CUDA GPU (CI's), run where one is.

The networks, losses and replay buffer live on the GPU, the envs' tensors too; Gymnasium's own
arrays and the checkpoints' readers stay on the CPU.
"""

from __future__ import annotations

import json

import pytest
import torch

from tests.conftest import SMOKE_OVERRIDES
from tests.test_pixels import TINY_PIXEL_RUN
from trl_cartpole.envs.cartpole_drawing import draw_cartpole
from trl_cartpole.policy.load import evaluate_checkpoint
from trl_cartpole.run.training import train
from trl_cartpole.store.checkpoint import (
    find_resume_checkpoint,
    read_checkpoint_config,
    resume_config,
)

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU here")


def test_frames_drawn_on_the_gpu_are_the_cpu_ones():
    generator = torch.Generator().manual_seed(0)
    state = (torch.rand(256, 4, generator=generator) - 0.5) * torch.tensor([4.0, 1.0, 0.4, 1.0])
    on_cpu = draw_cartpole(state, (120, 320, None, None), 10)  # [256, 1, 20, 60]
    on_gpu = draw_cartpole(state.cuda(), (120, 320, None, None), 10)
    assert on_gpu.device.type == "cuda" and on_gpu.shape == on_cpu.shape == (256, 1, 20, 60)
    # the same sums in another order: a gray level may round the other way, no more
    difference = (on_gpu.cpu().int() - on_cpu.int()).abs()
    assert difference.max() <= 1 and difference.float().mean() < 0.01


@pytest.mark.parametrize("algo", ["dqn", "rainbow"])
def test_a_run_on_the_gpu_trains_resumes_and_its_policy_plays_on_the_cpu(compose, tmp_path, algo):
    overrides = [*SMOKE_OVERRIDES, "checkpoint.interval_frames=100", f"run_dir={tmp_path}"]
    summary = train(compose(f"algo={algo}", "device=cuda", *overrides))
    assert summary["frames"] == 300 and summary["updates"] > 0
    assert len(summary["final_eval_returns"]) == 4
    checkpoint = find_resume_checkpoint(tmp_path)  # the training state goes back on the GPU
    more = train(resume_config(checkpoint, ["collector.total_frames=400"]), resume=checkpoint)
    assert more["frames"] == 400 and more["updates"] > summary["updates"]
    best = tmp_path / "checkpoints" / "best"
    assert read_checkpoint_config(best).device == "cuda"
    result, loaded = evaluate_checkpoint(str(best), episodes=2)  # loaded for the CPU
    assert loaded["device"] == "cpu" and len(result.returns) == 2


def test_a_pixel_run_on_the_gpu_trains_resumes_and_plays_on_the_cpu(compose, tmp_path):
    train(compose(*TINY_PIXEL_RUN, "device=cuda", f"run_dir={tmp_path}"))
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["frames"] == 200 and summary["updates"] > 0
    checkpoint = find_resume_checkpoint(tmp_path)
    with pytest.warns(UserWarning, match="starts new episodes"):
        train(resume_config(checkpoint, ["collector.total_frames=296"]), resume=checkpoint)
    assert json.loads((tmp_path / "summary.json").read_text())["frames"] == 296
    result, _ = evaluate_checkpoint(tmp_path, episodes=2)
    assert len(result.returns) == 2
