"""Sorting py-spy's sampled stacks into the training loop's phases."""

from __future__ import annotations

from trl_cartpole.profiling import frame_breakdown, parse_raw_stacks

LOOP = "<module> (train.py:40);train (trl_cartpole/train.py:300)"
UPDATE = f"{LOOP};update (trl_cartpole/update.py:57)"
COLLECT = f"{LOOP};_timed_batches (trl_cartpole/train.py:90);iterator (torchrl/collectors/c.py:1)"
SEQUENCE = "forward (tensordict/nn/sequence.py:626)"
RAW = f"""\
<module> (train.py:12);<module> (torch/__init__.py:1) 50
{UPDATE};forward (torchrl/objectives/dqn.py:310);{SEQUENCE} 7
{UPDATE};backward (torch/_tensor.py:623) 3
{COLLECT};{SEQUENCE} 4
{COLLECT};step_and_maybe_reset (torchrl/envs/common.py:4093) 5
{COLLECT} 2
{LOOP};run_evaluation (trl_cartpole/train.py:280);evaluate (trl_cartpole/evaluation.py:90) 9
{UPDATE};backward (torch/_tensor.py:623) 1
{LOOP} 1
"""


def test_raw_stacks_are_counted_per_distinct_stack():
    stacks = parse_raw_stacks(RAW.splitlines())
    assert sum(stacks.values()) == 82
    backward = next(stack for stack in stacks if "backward" in stack[-1])
    assert stacks[backward] == 4  # the two identical lines add up
    assert backward[0] == "<module> (train.py:40)"


def test_each_sample_goes_to_its_most_specific_phase_and_startup_is_left_out():
    phases = frame_breakdown(parse_raw_stacks(RAW.splitlines()))
    assert phases == {
        "evaluation (clock stopped)": 9,
        "loss forward (DQNLoss)": 7,  # the Q-network inside the loss is not "policy"
        "env step (Gymnasium + TorchRL transforms)": 5,
        "backward": 4,
        "policy (Q-network + epsilon-greedy)": 4,
        "collector bookkeeping": 2,
        "other loop work": 1,
    }
    assert sum(phases.values()) == 82 - 50  # the import samples are outside train()
