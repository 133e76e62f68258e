"""Evaluation with a given epsilon: the Practical RL seed's and the Atari protocol's check."""

from __future__ import annotations

import json
import weakref

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import OneHot
from torchrl.envs import Transform

from trl_cartpole.compat import gym_env
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.models import make_q_actor
from trl_cartpole.run.evaluation import (
    EpsilonGreedy,
    evaluate,
    evaluate_on_vector_env,
    evaluate_with_rollout,
)

from .conftest import run_script_in_process


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


@pytest.mark.parametrize(
    ("env_id", "observation_norm", "actor_kwargs"),
    [
        ("CartPole-v1", None, {}),  # the Q-network called on the observation tensor
        ("CartPole-v1", None, {"noisy": True, "head": "dueling"}),
        ("CartPole-v1", None, {"support": torch.linspace(0.0, 200.0, 51)}),  # C51
        ("MountainCar-v0", {"loc": [-0.5, 0.0], "scale": [0.5, 0.05]}, {}),  # the whole actor
    ],
)
def test_direct_vector_env_evaluation_plays_the_episodes_torchrl_rollout_plays(
    env_id, observation_norm, actor_kwargs
):
    def env():  # a fresh env: both paths start from the same seeded reset
        return make_env(env_id, seed=7, num_envs=12, observation_norm=observation_norm)

    torch.manual_seed(0)
    actor = make_q_actor(env().observation_spec, env().action_spec, **actor_kwargs)
    with torch.no_grad():  # a sharper random policy: episodes of different lengths
        for parameter in actor.parameters():
            parameter.mul_(3)
    direct, rollout = env(), env()
    fast = evaluate(actor, direct, max_steps=300)
    slow = evaluate_with_rollout(actor, rollout, max_steps=300, epsilon=0.0)
    assert fast.returns == slow.returns
    assert fast.lengths == slow.lengths
    assert fast.initial_values == pytest.approx(slow.initial_values)
    assert len(set(fast.initial_values)) == 12  # twelve different start states
    # the next evaluation continues the envs' random streams: new start states
    assert evaluate_on_vector_env(actor, direct, gym_env(direct), 300).initial_values != (
        fast.initial_values
    )


def test_evaluate_cli_epsilon_is_reported(smoke_checkpoint, tmp_path):
    out = tmp_path / "eval.json"
    proc = run_script_in_process(
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
    bad = run_script_in_process("evaluate.py", f"checkpoint={smoke_checkpoint}", "epsilon=2")
    assert bad.returncode == 2 and "error: epsilon=2.0 must lie in [0, 1]" in bad.stderr


@pytest.mark.parametrize(
    ("argument", "message"),
    [  # found by tests/test_fuzz.py: each was a traceback
        ("episodes=,", "'episodes=,' is not key=value with a value YAML can read"),
        ("seed='", "is not key=value with a value YAML can read"),
        ("seed=-1", "seed=-1 must be >= 0"),
        ("episodes=100000", "episodes=100000 would build that many envs at once; at most 4096"),
    ],
)
def test_evaluate_refuses_unreadable_or_impossible_arguments_in_one_line(
    smoke_checkpoint, tmp_path, argument, message
):
    output = tmp_path / "report.json"
    proc = run_script_in_process(
        "evaluate.py", f"checkpoint={smoke_checkpoint}", f"output={output}", argument
    )
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert proc.returncode == 2 and len(lines) == 1 and message in lines[0], proc.stderr[-1500:]
    assert not output.exists()


class _ObservationsAlive(Transform):
    """Gives each step's observation a tensor of its own and counts, at every step, how many
    of the earlier ones something still holds (weak references: a kept trajectory holds
    them all)."""

    def __init__(self) -> None:
        super().__init__(in_keys=[], out_keys=[])
        self.made: list[weakref.ref] = []
        self.most_alive = 0

    def _own(self, tensordict):
        observation = tensordict["observation"].clone()
        self.made.append(weakref.ref(observation))
        self.most_alive = max(self.most_alive, sum(ref() is not None for ref in self.made))
        return tensordict.set("observation", observation)

    def _step(self, tensordict, next_tensordict):
        return self._own(next_tensordict)

    def _reset(self, tensordict, tensordict_reset):
        return self._own(tensordict_reset)


def test_an_evaluation_holds_a_few_steps_not_the_episode():
    # MountainCar's episodes last their 200-step limit under an untrained greedy policy: an
    # evaluation that kept its trajectory (as env.rollout does) would hold all 200 steps
    env = make_env("MountainCar-v0", seed=0).append_transform(_ObservationsAlive())
    actor = make_q_actor(env.observation_spec, env.action_spec)
    counter = env.transform[-1]
    result = evaluate_with_rollout(actor, env, max_steps=1000, epsilon=0.0)
    assert result.lengths == [200]
    assert len(counter.made) == 201 and counter.most_alive <= 3  # 2 here
    kept = env.rollout(200, actor)  # the trajectory kept: every observation alive at once
    assert kept.shape == (200,) and counter.most_alive >= 200
