"""The state a run keeps inside its envs, its collector and its n-step window, as a component.

``torchrl.checkpoint.Checkpoint`` saves every component through ``state_dict()`` /
``load_state_dict()``. The networks, optimizer, exploration module, replay buffer, collector
counters, global RNGs and the loop's own objects (progress, learner, evaluator, history) have
their own; :class:`EnvState` gathers what lives inside TorchRL and Gymnasium objects, so that a
run resumed from a checkpoint continues exactly as if never stopped:

- the training and evaluation envs' state (:mod:`trl_cartpole.store.env_state`: data for
  classic-control envs, pickled only with ``checkpoint.trust_pickled_envs``);
- the in-process collector's carrier (the last observation and the running step count and
  return);
- for a synchronous multi-process collector, each worker's envs, carrier and torch RNG
  (:mod:`trl_cartpole.store.worker_state`); Ray actors' and asynchronous workers' envs are not
  saved, and their resumed runs start new episodes;
- the n-step window the replay buffer's ``MultiStepTransform`` holds back (it continues the
  training envs' episodes, so it is restored only with them).
"""

from __future__ import annotations

import warnings
from typing import Any

from tensordict import TensorDict
from torchrl.envs import EnvBase

from trl_cartpole.compat import carrier_of, held_steps, n_step_transform, set_held_steps
from trl_cartpole.store.env_state import (
    autoreset_snapshot,
    env_snapshot,
    restore_autoreset,
    restore_env_snapshot,
)
from trl_cartpole.store.worker_state import restore_worker_states, worker_states

__all__ = ["EnvState"]


class EnvState:
    """``state_dict`` / ``load_state_dict`` over the envs' and collector's state (module doc).

    ``trust_pickle`` (``checkpoint.trust_pickled_envs``) saves and loads envs that are not
    plain data with pickle.
    """

    def __init__(
        self, env: EnvBase | None, eval_env: EnvBase, collector, buffer, trust_pickle: bool = False
    ) -> None:
        self.env, self.eval_env = env, eval_env  # env: None when workers hold the training envs
        self.collector, self.buffer = collector, buffer
        self.trust_pickle = trust_pickle
        self.workers_answer = True  # False once a worker or Ray actor is lost

    def forget_workers(self) -> None:
        """A worker or Ray actor is lost: the next checkpoints do not ask the workers for their
        envs (a lost one never answers), and a resume from them starts the workers' episodes
        anew."""
        self.workers_answer = False

    def state_dict(self) -> dict[str, Any]:
        n_step = n_step_transform(self.buffer)
        window = None if n_step is None else held_steps(n_step)
        in_process = self.env is not None  # else the training envs live in the workers
        return {
            "workers": None
            if in_process or not self.workers_answer
            else worker_states(self.collector),
            "workers_lost": not self.workers_answer,
            "env": env_snapshot(self.env, self.trust_pickle) if in_process else None,
            "eval_env": env_snapshot(self.eval_env, self.trust_pickle),
            "env_autoreset": autoreset_snapshot(self.env) if in_process else None,
            "eval_env_autoreset": autoreset_snapshot(self.eval_env),
            "carrier": carrier_of(self.collector).to_dict() if in_process else None,
            "n_step_window": None if window is None else window.to_dict(),
            "n_step_window_size": None if window is None else list(window.batch_size),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        restored = {"env": False}
        if self.env is None:
            restored["env"] = restore_worker_states(self.collector, state.get("workers"))
            if not restored["env"]:
                warnings.warn(self._workers_not_restored(state), stacklevel=2)
        for env, key in ((self.env, "env"), (self.eval_env, "eval_env")):
            if env is None:
                continue
            restored[key] = restore_env_snapshot(env, state[key], self.trust_pickle)
            if not restored[key]:  # a fresh env: new episodes, and a fresh autoreset memo
                warnings.warn(self._not_restored(key, state[key]), stacklevel=2)
                if key == "env":  # start a new episode from the restored RNG
                    carrier_of(self.collector).update(env.reset())
                continue
            memo = state[f"{key}_autoreset"]
            if memo is not None:
                restore_autoreset(env, memo)
        # The carrier and the n-step window continue the training env's episodes: only with it.
        if restored["env"]:
            if self.env is not None:  # the workers' carriers were restored with their envs
                carrier = carrier_of(self.collector)
                carrier.update(TensorDict(state["carrier"], batch_size=carrier.batch_size))
            if state["n_step_window"] is not None:
                window = TensorDict(state["n_step_window"], batch_size=state["n_step_window_size"])
                set_held_steps(n_step_transform(self.buffer), window)

    @staticmethod
    def _workers_not_restored(state: dict[str, Any]) -> str:
        """Why the workers' envs start new episodes, in one line."""
        if state.get("workers_lost"):
            reason = (
                "the checkpoint was written after a worker or Ray actor was lost, when the "
                "workers could no longer all be read"
            )
        else:
            reason = (
                "collection runs in asynchronous workers or Ray actors (collector.sync=false: "
                "no moment between batches to read them), or in worker envs whose state is not "
                "stored as data"
            )
        return f"{reason}: the resumed run's workers start new episodes (not an exact continuation)"

    def _not_restored(self, key: str, snapshot: Any) -> str:
        name = key.replace("_", " ")
        pickled = "pickle" in (snapshot or {})
        if pickled and not self.trust_pickle:
            return (
                f"the {name}'s state was stored pickled, and unpickling runs any code the "
                "checkpoint holds, so it was not loaded: the resumed run starts new episodes (not "
                "an exact continuation); pass checkpoint.trust_pickled_envs=true to load it if you "
                "wrote this checkpoint"
            )
        if "replay" in (snapshot or {}):
            return (
                f"the {name}'s logged episodes, played again, did not reach the saved "
                "observations (an env not deterministic given its random generator and actions, "
                "or envs other than the saved ones), so the resumed run starts new episodes (not "
                "an exact continuation)"
            )
        return (
            f"the {name}'s state is not stored as data (classic-control envs' and Atari games' "
            "are) and no episode log of it was (an env not built by make_env, an episode over "
            "100 000 steps, reset options that are not plain data, pixels Gymnasium renders), "
            "so the resumed run starts new episodes (not an exact continuation)"
        )
