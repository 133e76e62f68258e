"""Every earlier form this project still reads, in one place, each with its end announced.

The factories take the names and call forms of the TorchRL classes they build. Where this
project first used another name, call form or saved layout, it still works until version
:data:`REMOVED_IN`, with a ``FutureWarning`` that names what to write instead (as TorchRL
deprecates); CHANGELOG.md's "Deprecations" lists them:

- argument aliases: ``action_spec`` (``spec``), ``hidden_sizes`` (``num_cells``),
  ``activation`` (``activation_class``), ``hard_update_interval``
  (``value_network_update_interval`` + 1);
- ``make_target_updater(loss, "soft")``: the kind as the second positional argument;
- a plain Q-network saved before it became one TorchRL ``MLP`` (:class:`EarlierLayoutKeys`);
- an evaluator state saved before its memory curve or its candidates
  (:func:`upgrade_evaluator_state`);
- a run's config saved before ``env.atari.fire_steps`` (:func:`upgrade_stored_config`);
- a training state whose curves were saved as lists, before they became tensors
  (:func:`history_curves`).
"""

from __future__ import annotations

import warnings
from typing import Any, TypeVar

__all__ = [
    "REMOVED_IN",
    "EarlierLayoutKeys",
    "history_curves",
    "resolve_alias",
    "upgrade_evaluator_state",
    "upgrade_stored_config",
    "warn_earlier_form",
]

T = TypeVar("T")

REMOVED_IN = "0.3.0"  # the version the earlier forms below go away in


def warn_earlier_form(what: str, instead: str, stacklevel: int = 3) -> None:
    """A ``FutureWarning``: ``what`` still works until :data:`REMOVED_IN`; write ``instead``."""
    warnings.warn(
        f"{what} is an earlier form, read until trl_cartpole {REMOVED_IN}; write {instead}",
        FutureWarning,
        stacklevel=stacklevel,
    )


def resolve_alias(name: str, value: T | None, alias: str, alias_value: T | None) -> T | None:
    """``value``, or ``alias_value`` when only the alias was given (with a ``FutureWarning``);
    both given: ``TypeError``."""
    if alias_value is None:
        return value
    if value is not None:
        raise TypeError(f"{alias}= is an alias of {name}=; pass one of them")
    warn_earlier_form(f"{alias}=", f"{name}=", stacklevel=4)
    return alias_value


class EarlierLayoutKeys:
    """A load-time renaming for a plain Q-network saved in this project's earlier layout.

    Policies saved before the plain network became one ``MLP`` (TorchRL's layout, keys
    ``0.weight``, ``2.weight``...) hold ``Sequential(torso MLP, head)``: keys ``0.{j}.*`` for
    the torso's layer ``j`` and ``1.*`` (``1.0.*`` for C51) for the head. The hook renames them
    (picklable, so worker processes receive the actor).
    """

    def __init__(self, last_linear: int) -> None:
        self.last_linear = last_linear

    def __call__(self, state_dict: dict[str, Any], prefix: str, *_: Any) -> None:
        if not any(key.startswith(f"{prefix}0.0.") for key in state_dict):
            return  # TorchRL's layout already
        warn_earlier_form(
            "a policy saved in the network layout before TorchRL's MLP",
            "it again (save the loaded policy, or train it anew)",
            stacklevel=2,
        )
        renamed = {}  # all at once: a new name may be another old one (0.1.* -> 1.*)
        for key in [key for key in state_dict if key.startswith(prefix)]:
            layer, _, name = key[len(prefix) :].partition(".")
            if layer == "0":  # the torso: 0.{j}.name -> {j}.name
                new = name
            else:  # the head: 1.name, or 1.0.name for C51's Sequential(linear, Unflatten)
                new = f"{self.last_linear}.{name[2:] if name.startswith('0.') else name}"
            renamed[prefix + new] = state_dict.pop(key)
        state_dict.update(renamed)


def upgrade_evaluator_state(state: dict[str, Any]) -> dict[str, Any]:
    """An evaluator state in today's layout: a state from before the memory curve gets no
    readings (None) for its earlier evaluations; one from before the candidates gets its
    best policy as the one candidate, at the frames of the evaluation that found it."""
    state = dict(state)
    curve = dict(state["curve"])
    missing = len(curve["frames"]) - len(curve.get("rss_mb", []))
    if missing:
        curve["rss_mb"] = [None] * missing + list(curve.get("rss_mb", []))
    state["curve"] = curve
    if state.get("candidates") is None and state["best_state"] is not None:
        frames = next(
            (
                f
                for f, mean in zip(curve["frames"], curve["returns"], strict=True)
                if mean == state["best_return"]
            ),
            0,
        )
        state["candidates"] = {
            "frames": [frames],
            "returns": [state["best_return"]],
            "states": [state["best_state"]],
        }
    return state


def upgrade_stored_config(config: dict[str, Any]) -> dict[str, Any]:
    """A run's stored config (a dict) in today's layout, meaning what it meant when saved: a
    config saved before ``env.atari.fire_steps`` trained and was judged with one FIRE step
    after a reset and a lost life, so it reads as ``fire_steps: 1`` (today's default is 2),
    and its evaluations, exports, plain-loop replays and resumes keep that rule."""
    atari = (config.get("env") or {}).get("atari")
    if atari is None or "fire_steps" in atari:
        return config
    env = {**config["env"], "atari": {**atari, "fire_steps": 1}}
    return {**config, "env": env}


def history_curves(state: dict[str, Any]) -> dict[str, list]:
    """A saved history's curves as lists: today's tensors read back, or the lists a training
    state held before its curves became tensors (as they were)."""
    return {
        name: values.tolist() if hasattr(values, "tolist") else list(values)
        for name, values in state.items()
    }
