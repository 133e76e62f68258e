"""The policy a run keeps: the evaluator's best few candidates and the choice among them."""

from __future__ import annotations

import json

import pytest
import torch
from torch import nn
from torchrl.checkpoint import Checkpoint

from trl_cartpole.config.schema import Config
from trl_cartpole.run.best_policy import choose_best_policy
from trl_cartpole.run.eval_protocol import EvalProtocol
from trl_cartpole.run.evaluation import EvalResult, Evaluator
from trl_cartpole.run.progress import Progress
from trl_cartpole.run.training import train

from .conftest import SMOKE_OVERRIDES


def _evaluator_over(means: list[float], candidates: int) -> tuple[Evaluator, nn.Linear]:
    """An evaluator whose evaluations give ``means`` in turn; before each the network's bias
    is set to the evaluation's number, so a kept state says which evaluation it came from."""
    network = nn.Linear(1, 1)
    turns = iter(means)
    evaluator = Evaluator(
        lambda: EvalResult(returns=[next(turns)], lengths=[1], initial_values=[0.0]),
        network,
        interval_frames=10,
        threshold=None,
        candidates=candidates,
    )
    progress = Progress()
    for number in range(len(means)):
        with torch.no_grad():
            network.bias.fill_(number)
        progress.frames = 10 * (number + 1)
        evaluator.run(progress)
    return evaluator, network


def _numbers(evaluator: Evaluator) -> list[int]:
    return [int(candidate.state["bias"].item()) for candidate in evaluator.candidates]


def test_the_evaluator_keeps_the_best_few_policies_best_first_the_earlier_on_a_tie():
    evaluator, _ = _evaluator_over([10.0, 30.0, 20.0, 30.0, 25.0, 5.0], candidates=3)
    # means by evaluation: 0:10 1:30 2:20 3:30 4:25 5:5 -> 1 (30, first), 3 (30), 4 (25)
    assert _numbers(evaluator) == [1, 3, 4]
    assert [c.frames for c in evaluator.candidates] == [20, 40, 50]
    assert [c.eval_return_mean for c in evaluator.candidates] == [30.0, 30.0, 25.0]
    assert evaluator.best_state is evaluator.candidates[0].state  # one copy of the best
    assert evaluator.best_return == 30.0


def test_one_candidate_is_the_best_periodic_policy_as_before():
    evaluator, network = _evaluator_over([10.0, 30.0, 20.0], candidates=1)
    assert _numbers(evaluator) == [1]
    kept, scores = choose_best_policy(
        EvalProtocol.from_config(Config()), evaluator, play=pytest.fail
    )  # plays nothing
    assert kept is evaluator.candidates[0] and scores == []
    assert network.bias.item() == 1.0  # the best's weights are in the network


def test_the_candidate_best_over_new_episodes_is_kept_and_in_the_network():
    evaluator, network = _evaluator_over([10.0, 30.0, 20.0, 29.0], candidates=3)
    assert _numbers(evaluator) == [1, 3, 2]
    new_means = {1: 400.0, 3: 480.0, 2: 470.0}  # the periodic best plays worse than 3
    played = []

    def play(seed: int, episodes: int) -> EvalResult:
        number = int(network.bias.item())  # the candidate whose weights are in the network
        played.append((number, seed, episodes))
        return EvalResult(returns=[new_means[number]] * episodes)

    cfg = Config()
    cfg.seed, cfg.eval.candidate_episodes = 7, 5
    protocol = EvalProtocol.from_config(cfg)
    kept, scores = choose_best_policy(protocol, evaluator, play)
    seed = protocol.seed_for("candidates")
    assert seed == 7 + 3 * cfg.eval.seed_offset == 3_000_007
    # every candidate plays the same episodes: the same first seed, the same count
    assert played == [(1, seed, 5), (3, seed, 5), (2, seed, 5)]
    assert [s.replay_return_mean for s in scores] == [400.0, 480.0, 470.0]
    assert [s.frames for s in scores] == [20, 40, 30]
    assert kept is evaluator.candidates[1] and network.bias.item() == 3.0
    assert evaluator.best_state is kept.state  # what the run saves and evaluates last


def test_a_tie_over_new_episodes_keeps_the_better_periodic_candidate():
    evaluator, network = _evaluator_over([10.0, 30.0, 20.0], candidates=2)
    kept, _ = choose_best_policy(
        EvalProtocol.from_config(Config()),
        evaluator,
        lambda seed, episodes: EvalResult(returns=[500.0]),
    )
    assert kept is evaluator.candidates[0] and network.bias.item() == 1.0


def test_candidates_survive_a_checkpoint(tmp_path):
    evaluator, _ = _evaluator_over([10.0, 30.0, 20.0], candidates=2)
    Checkpoint(evaluator=evaluator).save(tmp_path / "state")
    loaded = Evaluator(lambda: None, nn.Linear(1, 1), 10, None, candidates=2)
    Checkpoint(evaluator=loaded).load(tmp_path / "state")
    assert _numbers(loaded) == [1, 2]
    assert [c.frames for c in loaded.candidates] == [20, 30]


@pytest.mark.parametrize("candidates", [pytest.param(1, marks=pytest.mark.slow), 2])
def test_a_run_records_the_best_policy_and_saves_it_as_best(compose, tmp_path, candidates):
    overrides = [o for o in SMOKE_OVERRIDES if not o.startswith("eval.interval_frames")]
    cfg = compose(
        *overrides,
        "eval.interval_frames=60",
        f"eval.candidates={candidates}",
        "eval.candidate_episodes=3",
        f"run_dir={tmp_path / 'run'}",
    )
    summary = train(cfg)
    curve = summary["eval_curve"]
    manifest = Checkpoint.manifest(tmp_path / "run" / "checkpoints" / "best")["metadata"]
    assert manifest["frames"] == summary["best_policy_frames"]
    if candidates == 1:
        assert "candidates" not in summary
        best = curve["returns"].index(max(curve["returns"]))
        assert summary["best_policy_frames"] == curve["frames"][best]
        return
    scores = summary["candidates"]
    ranked = sorted(zip(curve["returns"], curve["frames"], strict=True), key=lambda p: -p[0])
    assert [s["eval_return_mean"] for s in scores] == [mean for mean, _ in ranked[:2]]
    assert len({s["frames"] for s in scores}) == 2
    kept = max(scores, key=lambda s: s["replay_return_mean"])
    assert summary["best_policy_frames"] == kept["frames"]
    saved = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert saved["candidates"] == scores
