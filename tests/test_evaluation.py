"""Evaluation with a given epsilon: the Practical RL seed's and the Atari protocol's check."""

from __future__ import annotations

import json

import torch
from tensordict import TensorDict
from torchrl.data import OneHot

from trl_cartpole.envs import make_env
from trl_cartpole.evaluation import EpsilonGreedy, evaluate
from trl_cartpole.models import make_q_actor

from .conftest import run_script


def test_epsilon_greedy_replaces_a_fraction_of_actions_even_in_deterministic_mode():
    torch.manual_seed(0)
    greedy = torch.tensor([1, 0]).expand(20_000, 2)  # always action 0
    module = EpsilonGreedy(OneHot(2), epsilon=0.3)
    out = module(TensorDict(action=greedy.clone(), batch_size=[20_000]))
    switched = (out["action"].argmax(-1) == 1).float().mean().item()
    assert abs(switched - 0.15) < 0.01  # eps * P(random pick is the other action) = 0.3 / 2


def test_epsilon_zero_is_the_greedy_evaluation_and_one_is_random():
    def env():  # the same 30 start states each time
        return make_env("CartPole-v1", seed=5, num_envs=30)

    torch.manual_seed(0)
    actor = make_q_actor(env().observation_spec, env().action_spec)
    greedy = evaluate(actor, env())
    again = evaluate(actor, env(), epsilon=0.0)
    uniform = evaluate(actor, env(), epsilon=1.0)
    assert greedy.returns == again.returns
    assert greedy.returns != uniform.returns


def test_evaluate_cli_epsilon_is_reported(smoke_checkpoint, tmp_path):
    out = tmp_path / "eval.json"
    proc = run_script(
        "evaluate.py",
        f"checkpoint={smoke_checkpoint}",
        "episodes=30",
        "epsilon=0.05",
        f"output={out}",
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = json.loads(out.read_text())
    assert report["epsilon"] == 0.05 and report["episodes"] == 30 == len(report["returns"])
    assert "epsilon=0.05 return over 30 episodes" in proc.stdout
    bad = run_script("evaluate.py", f"checkpoint={smoke_checkpoint}", "epsilon=2")
    assert bad.returncode == 2 and "error: epsilon=2.0 must lie in [0, 1]" in bad.stderr
