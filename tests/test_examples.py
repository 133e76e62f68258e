"""The reuse examples run as a user runs them, on short budgets, and build what they say."""

from __future__ import annotations

import runpy
from pathlib import Path

import pytest
import torch
from torchrl.collectors import Collector
from torchrl.data import TensorDictReplayBuffer
from torchrl.modules import EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, HardUpdate, SoftUpdate

from trl_cartpole.parts.models import DuelingHead

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _main(name: str):
    return runpy.run_path(str(EXAMPLES / name), run_name=name)["main"]


def _target_moved(loss: DQNLoss, initial: list[torch.Tensor]) -> bool:
    now = list(loss.target_value_network_params.values(True, True))
    return any(not torch.equal(a, b) for a, b in zip(now, initial, strict=True))


def test_torchrl_dqn_example_runs_on_the_factories():
    budget = "--frames 1500 --init-random-frames 500 --annealing-frames 500 --test-interval 1000"
    out = _main("torchrl_dqn_example.py")(budget.split())
    assert isinstance(out["model"], QValueActor)
    assert type(out["greedy_module"]) is EGreedyModule
    assert out["greedy_module"].eps.item() == pytest.approx(0.05)  # annealed over 500 frames
    assert isinstance(out["collector"], Collector) and out["frames"] == 1500
    assert isinstance(out["replay_buffer"], TensorDictReplayBuffer)
    assert len(out["replay_buffer"]) == 1500
    loss = out["loss_module"]
    assert isinstance(loss, DQNLoss) and loss.loss_function == "l2"
    assert loss.value_estimator.gamma.item() == pytest.approx(0.99)
    updater = out["target_net_updater"]
    assert isinstance(updater, HardUpdate) and updater.value_network_update_interval == 50
    # one update per batch of 10 frames from 500 frames on (500, 510, ..., 1500): 101 updates,
    # so the hard copy (on the 51st step) happened
    assert len(out["losses"]) == 101 and torch.isfinite(torch.tensor(out["losses"])).all()
    assert _target_moved(loss, out["initial_target"])
    assert len(out["test_returns"]) == 1 and 1 <= out["test_returns"][0] <= 500


@pytest.mark.slow  # an example run in a fresh interpreter
def test_dueling_double_acrobot_example_runs_its_own_loop():
    out = _main("dueling_double_acrobot.py")(["--frames", "1600"])
    actor = out["actor"]
    assert isinstance(actor, QValueActor)
    assert any(isinstance(m, DuelingHead) for m in actor.modules())
    assert type(out["exploration"]) is EGreedyModule
    assert out["exploration"].eps.item() < 1.0  # annealing started
    loss = out["loss"]
    assert isinstance(loss, DQNLoss) and loss.double_dqn
    assert loss.value_estimator.gamma.item() == pytest.approx(0.99)  # the buffer's n-step gamma
    assert isinstance(out["target"], SoftUpdate) and out["target"].eps == pytest.approx(0.99)
    assert isinstance(out["buffer"], TensorDictReplayBuffer) and out["frames"] == 1600
    # 50 batches of 32 frames; updates from the first batch with 1 000 stored transitions on
    assert 0 < len(out["losses"]) < 4 * 50
    assert torch.isfinite(torch.tensor(out["losses"])).all()
    assert _target_moved(loss, out["initial_target"])
    assert -500.0 <= out["greedy_return"] <= 0.0


def test_the_factories_drop_into_torchrls_dqn_trainer():
    out = _main("dqn_trainer.py")(["--frames", "1600"])
    trainer, loss = out["trainer"], out["loss"]
    assert isinstance(loss, DQNLoss) and trainer.loss_module is loss
    assert trainer.collected_frames == 1600
    assert out["exploration"].eps.item() < 1.0  # the trainer stepped epsilon
    assert 1.0 <= out["greedy_return"] <= 500.0


def test_your_own_network_trains_under_the_factories_parts():
    out = _main("own_network.py")(["--frames", "1600"])
    actor, torso = out["actor"], out["torso"]
    assert isinstance(actor, QValueActor)
    assert any(module is torso for module in actor.modules())  # the user's module, as given
    assert any(isinstance(m, DuelingHead) for m in actor.modules())
    assert any(isinstance(m, torch.nn.LayerNorm) for m in actor.modules())
    # 50 batches of 32 frames, 2 updates each once 1 000 transitions are stored
    assert 0 < len(out["losses"]) < 2 * 50
    assert torch.isfinite(torch.tensor(out["losses"])).all()
    assert 1.0 <= out["greedy_return"] <= 500.0


@pytest.mark.slow  # 200 Breakout steps and 25 CNN updates
def test_an_atari_game_trains_in_your_own_loop_with_the_frame_storage_and_learner_view():
    pytest.importorskip("ale_py")
    from trl_cartpole.envs.atari import EOL_KEY, LearnerView
    from trl_cartpole.storage.frames import FrameStackStorage

    out = _main("atari_breakout.py")(["--steps", "200"])
    assert out["actor"].in_keys == ["pixels"]  # found in the spec, not passed
    buffer = out["buffer"]
    assert isinstance(buffer.storage, FrameStackStorage)
    assert any(isinstance(t, LearnerView) for t in buffer.transform)
    # 50 batches of 4 steps; updates from the batch where 100 transitions are stored
    assert 24 <= len(out["losses"]) <= 26 and torch.isfinite(torch.tensor(out["losses"])).all()
    sample = buffer.sample()  # [32]
    assert sample["pixels"].shape == (32, 4, 84, 84) and sample["pixels"].dtype == torch.uint8
    # each step's reward clipped to its sign before the 3-step sum (a brick scores up to 7)
    assert sample["next", "reward"].abs().max() <= 1 + 0.99 + 0.99**2 + 1e-6
    lost = sample["next", EOL_KEY]
    assert sample["next", "terminated"][lost].all()  # a lost life ends the learner's episode
