"""rl-zoo3's tuned DQN settings for an env, read from the ``hyperparams/dqn.yml`` its wheel ships.

rl-zoo3 cannot be installed beside this project's lock (``constraints.txt``: its
``pytablewriter`` -> ``typepy[datetime]`` needs ``python-dateutil<3``, the lock has 4), so its
wheel is downloaded once, without dependencies, into ``runs/peer-venvs/rl_zoo3-<version>``
(``pip download rl_zoo3==<version> --no-deps``) and the file read from it: the settings are the
package's own, never a hand copy. ``policy_kwargs`` (a Python expression in the file, such as
``"dict(net_arch=[256, 256])"``) is read as literals only. :func:`train_with_zoo_settings`
trains a Stable-Baselines3-style ``DQN`` (SB3's, SBX's) with them under the protocol.
"""

from __future__ import annotations

import argparse
import ast
import subprocess
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from benchmarks.peers.protocol import PeerRun

__all__ = ["ZOO_VERSION", "train_with_zoo_settings", "zoo_dqn_settings"]

ZOO_VERSION = "2.9.2"
ZOO_DIR = Path(__file__).resolve().parents[2] / "runs" / "peer-venvs" / f"rl_zoo3-{ZOO_VERSION}"
NOT_SETTINGS = ("n_timesteps", "policy")  # the budget, and MlpPolicy (the peer's own)
# entries that change the env (wrappers, stacking, normalisation): not an MLP peer's race
ENV_CHANGES = ("env_wrapper", "frame_stack", "normalize")


def _wheel() -> Path:
    """The rl-zoo3 wheel, downloaded on first use."""
    found = sorted(ZOO_DIR.glob("rl_zoo3-*.whl"))
    if not found:
        command = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "-d", str(ZOO_DIR)]
        done = subprocess.run(
            [*command, f"rl_zoo3=={ZOO_VERSION}"], check=False, capture_output=True, text=True
        )
        if done.returncode != 0:  # pip's own words only when it failed: the console stays quiet
            sys.stderr.write(done.stderr)
            raise SystemExit(
                f"error: could not download rl_zoo3=={ZOO_VERSION} (its settings are read from "
                f"the wheel): put the wheel in {ZOO_DIR}, or run where PyPI is reachable"
            )
        found = sorted(ZOO_DIR.glob("rl_zoo3-*.whl"))
    return found[0]


def _policy_kwargs(text: str) -> dict[str, Any]:
    """``"dict(net_arch=[256, 256])"`` -> ``{"net_arch": [256, 256]}`` (literals only)."""
    call = ast.parse(text, mode="eval").body
    if not (isinstance(call, ast.Call) and getattr(call.func, "id", None) == "dict"):
        raise ValueError(f"policy_kwargs {text!r} is not dict(...) of literals")
    return {keyword.arg: ast.literal_eval(keyword.value) for keyword in call.keywords}


def zoo_dqn_settings(env_id: str) -> tuple[dict[str, Any], int]:
    """``(DQN keyword arguments, n_timesteps)`` rl-zoo3 tunes for ``env_id``."""
    with zipfile.ZipFile(_wheel()) as wheel:
        table = yaml.safe_load(wheel.read("rl_zoo3/hyperparams/dqn.yml"))
    if env_id not in table:
        known = ", ".join(key for key in table if "-v" in key)
        raise SystemExit(
            f"error: rl-zoo3 {ZOO_VERSION} has no DQN settings for {env_id}; it has: {known}"
        )
    entry = dict(table[env_id])
    changes = [key for key in ENV_CHANGES if key in entry]
    if changes:
        raise SystemExit(
            f"error: rl-zoo3's DQN entry for {env_id} changes the env ({', '.join(changes)}), "
            "which this peer does not reproduce: race another env"
        )
    timesteps = int(entry["n_timesteps"])
    settings = {key: value for key, value in entry.items() if key not in NOT_SETTINGS}
    if "policy_kwargs" in settings:
        settings["policy_kwargs"] = _policy_kwargs(settings["policy_kwargs"])
    return settings, timesteps


def train_with_zoo_settings(
    name: str,
    dqn_class: Callable[..., Any],
    args: argparse.Namespace,
    watch: Callable[[PeerRun, Any], None],
) -> dict:
    """Train ``dqn_class`` (Stable-Baselines3's ``DQN``, or one that takes its arguments) with
    rl-zoo3's settings for ``args.env_id`` under the protocol; ``watch(run, model)`` shows the
    run the model's Q-network. Returns the run's summary."""
    from stable_baselines3.common.callbacks import BaseCallback

    run = PeerRun(name, args)
    settings, timesteps = zoo_dqn_settings(args.env_id)
    fraction = settings.get("exploration_fraction", 0.1)  # SB3's default where zoo sets none
    settings["exploration_fraction"] = fraction * timesteps / args.total_frames  # zoo's, in steps
    model = dqn_class("MlpPolicy", args.env_id, seed=args.seed, device="cpu", verbose=0, **settings)
    watch(run, model)

    class ProtocolCallback(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps % args.eval_interval:
                return True
            return not run.evaluate(self.num_timesteps)

    model.learn(total_timesteps=args.total_frames, callback=ProtocolCallback())
    return run.finish(model.num_timesteps, model._n_updates)
