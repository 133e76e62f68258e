"""Where a training frame's time goes: py-spy's sampled stacks sorted into the loop's phases.

``py-spy record -f raw`` writes one line per distinct stack, ``frame;frame;...;frame COUNT``,
outermost first. :func:`frame_breakdown` gives each sample to the first phase (in
:data:`PHASES` order) that one of its frames names, so the phases are disjoint and add up to
the samples taken inside ``train()``'s loop.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable

__all__ = ["PHASES", "frame_breakdown", "parse_raw_stacks"]

# (phase, substrings of a stack frame that mark it), most specific first.
PHASES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("evaluation (clock stopped)", ("evaluate (trl_cartpole/evaluation.py",)),
    ("setup (envs, networks, buffer)", ("make_env (trl_cartpole/envs.py",)),
    ("checkpointing", ("save_state (trl_cartpole/train.py", "save_training_state")),
    ("replay sample", ("sample (torchrl/data/replay_buffers",)),
    ("loss forward (DQNLoss)", ("forward (torchrl/objectives/",)),
    ("backward", ("backward (torch/_tensor.py",)),
    ("gradient clipping", ("clip_grad",)),
    ("optimizer step", ("torch/optim/",)),
    ("target update (SoftUpdate/HardUpdate)", ("step (torchrl/objectives/utils.py",)),
    ("replay extend", ("extend_with_batch (trl_cartpole/buffers.py", "extend (torchrl/data/")),
    ("policy (Q-network + epsilon-greedy)", ("tensordict/nn/sequence.py",)),
    ("env step (Gymnasium + TorchRL transforms)", ("step_and_maybe_reset",)),
    ("policy weight sync", ("update_policy_weights_",)),
    ("collector bookkeeping", ("(torchrl/collectors/",)),
    ("epsilon schedule", ("EGreedyModule.step",)),
    ("episode statistics", ("_record_episodes (trl_cartpole/train.py",)),
    ("logging and progress bar", ("_log (trl_cartpole/train.py", "tqdm/")),
)
LOOP_MARK = "train (trl_cartpole/train.py"


def parse_raw_stacks(lines: Iterable[str]) -> Counter[tuple[str, ...]]:
    """``{stack (outermost first): samples}`` from py-spy's raw (collapsed) output."""
    stacks: Counter[tuple[str, ...]] = Counter()
    for line in lines:
        line = line.rstrip("\n")
        if not line:
            continue
        stack, _, count = line.rpartition(" ")
        stacks[tuple(stack.split(";"))] += int(count)
    return stacks


def frame_breakdown(stacks: Counter[tuple[str, ...]]) -> dict[str, int]:
    """Samples per phase of the stacks inside ``train()``, plus ``other loop work``.

    Samples outside ``train()`` (imports, Hydra, interpreter start) are left out.
    """
    phases: Counter[str] = Counter()
    for stack, count in stacks.items():
        if not any(LOOP_MARK in frame for frame in stack):
            continue  # imports, start-up, or after train() returned
        phase = next(
            (
                name
                for name, marks in PHASES
                if any(mark in frame for frame in stack for mark in marks)
            ),
            "other loop work",
        )
        phases[phase] += count
    return dict(phases.most_common())
