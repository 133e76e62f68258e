"""A run's curves saved with its training state: tensors that come back exactly."""

from __future__ import annotations

from dataclasses import fields

import torch
from torchrl.checkpoint import Checkpoint

from trl_cartpole.run.history import History


def _history() -> History:
    history = History()
    history.episode_returns[:] = [9.0, 0.1 + 0.2, 1e-300]  # float64 values float32 cannot hold
    history.episode_lengths[:] = [9, 10, 2**40]
    history.episode_frames[:] = [32, 64, 96]
    history.td_losses[:] = [0.5, 1 / 3]
    history.grad_norms[:] = [2.0, 3.5]
    history.update_frames[:] = [64, 64]
    return history


def test_the_curves_are_saved_as_tensors_and_read_back_exactly(tmp_path):
    history = _history()
    state = history.state_dict()
    for curve in fields(History):  # each curve's type from its annotation
        assert curve.type in ("list[float]", "list[int]"), curve
        float_curve = curve.type == "list[float]"
        assert state[curve.name].dtype == (torch.float64 if float_curve else torch.int64)
    assert state["epsilons"].shape == (0,)  # an empty curve stays one
    saved = Checkpoint(history=history).save(tmp_path / "state")
    schema = list(tmp_path.rglob("*.json"))
    assert schema and all("0.30000000000000004" not in path.read_text() for path in schema)
    restored = History()
    Checkpoint(history=restored).load(saved)
    assert restored == history
    assert type(restored.episode_lengths[2]) is int and type(restored.td_losses[1]) is float


class ListsHistory(History):
    """A history saved as training states of format 4 saved it: its curves as lists."""

    def state_dict(self):
        return {name: list(values) for name, values in vars(self).items()}
