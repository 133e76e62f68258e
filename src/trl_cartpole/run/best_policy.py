"""The policy a run keeps: its best periodic evaluation's, or the best of a few played again.

The best of many noisy means is biased upward (the winner's curse): the policy chosen for its
highest periodic mean plays worse on new episodes (docs/environments-measured.md).
With ``eval.candidates=K`` the evaluator keeps the K policies with the highest periodic means;
before the final evaluation each plays ``eval.candidate_episodes`` new episodes, the same
episodes for every candidate (the protocol's candidate seeds, neither the periodic evaluations'
nor the final's: :mod:`trl_cartpole.run.eval_protocol`), and the candidate with the highest mean
over them is kept (the best periodic one on a tie). The final evaluation then measures the
best policy on episodes no choice was made on.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from trl_cartpole.run.eval_protocol import EvalProtocol
from trl_cartpole.run.evaluation import Candidate, EvalResult, Evaluator

__all__ = ["CandidateScore", "choose_best_policy"]


@dataclass
class CandidateScore:
    """A candidate's periodic mean and its mean over the episodes it played again."""

    frames: int
    eval_return_mean: float  # the periodic evaluation that made it a candidate
    replay_return_mean: float  # over eval.candidate_episodes new episodes


def choose_best_policy(
    protocol: EvalProtocol,
    evaluator: Evaluator,
    play: Callable[[int, int], EvalResult] | None = None,
    on_candidate: Callable[[int, int], None] | None = None,
) -> tuple[Candidate | None, list[CandidateScore]]:
    """Play each of ``evaluator.candidates`` again, keep the best, put it into the network.

    :param protocol: the run's protocol: the candidates' seeds and episodes.
    :param play: ``play(seed, episodes)`` plays the network's greedy episodes from ``seed`` on;
        default: ``protocol.play`` with the evaluator's network.
    :param on_candidate: called with (candidate number from 1, candidates) before each plays.
    :returns: the kept candidate and every candidate's score, best periodic first; no scores
        when there is a single candidate (nothing to choose: nothing is played).
    """
    if play is None:

        def play(seed: int, episodes: int) -> EvalResult:
            return protocol.play(evaluator.network, seed, episodes)

    candidates = evaluator.candidates
    if len(candidates) <= 1:  # the best periodic evaluation's policy, as is
        evaluator.load_best()
        return (candidates[0] if candidates else None), []
    scores = []
    for number, candidate in enumerate(candidates, start=1):
        if on_candidate is not None:
            on_candidate(number, len(candidates))
        evaluator.network.load_state_dict(candidate.state)
        result = play(protocol.seed_for("candidates"), protocol.candidate_episodes)
        scores.append(CandidateScore(candidate.frames, candidate.eval_return_mean, result.mean))
    best = max(range(len(scores)), key=lambda i: (scores[i].replay_return_mean, -i))
    evaluator.keep(candidates[best])
    return candidates[best], scores
