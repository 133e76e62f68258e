"""SBX (Stable-Baselines3 in JAX) DQN with rl-zoo3's tuned settings, under the benchmark protocol.

    python -m benchmarks run --algos dqn --peers sbx_dqn --seeds 0 1 2
    runs/peer-venvs/sbx_dqn/bin/python -m benchmarks.peers.sbx_dqn --seed 0 \\
        --run-dir runs/peers/sbx_dqn-seed0               # one run, once that venv exists

``sbx-rl`` needs JAX, flax and optax, so it runs from a virtual environment of its own
(``benchmarks.harness.PEER_VENVS``), made on first use. Its ``DQN`` takes Stable-Baselines3's
arguments, so the settings, their rescaled exploration and the protocol are those of
:mod:`benchmarks.peers.sb3_dqn` (rl-zoo3 2.9.2's ``dqn.yml``; SBX's Q-network is two hidden
layers of ``net_arch[0]`` units: [256, 256] for CartPole, as zoo asks). XLA runs on one CPU
thread, as every other run of the benchmark does (``XLA_FLAGS``, set before JAX is imported).
The protocol evaluates and keeps the flax network's parameters through :class:`FlaxQValues`.
"""

from __future__ import annotations

import os

import numpy as np
import torch

from benchmarks.peers.protocol import parse_peer_args
from benchmarks.peers.sb3_dqn import train_with_zoo_settings

ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


class FlaxQValues(torch.nn.Module):
    """An SBX DQN's Q-network as the protocol reads a torch one: observations ``[E, obs]``
    float32 -> action values ``[E, A]``; its ``state_dict`` holds the flax parameters (JAX
    arrays, never changed in place), which ``load_state_dict`` puts back."""

    def __init__(self, policy) -> None:
        super().__init__()
        self.policy = policy  # sbx.dqn.policies.DQNPolicy: its qf_state is replaced each update

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        state = self.policy.qf_state
        return torch.from_numpy(np.array(state.apply_fn(state.params, observations.numpy())))

    def state_dict(self, *args, **kwargs) -> dict:
        return {"params": self.policy.qf_state.params}

    def load_state_dict(self, state_dict: dict, *args, **kwargs) -> None:
        self.policy.qf_state = self.policy.qf_state.replace(params=state_dict["params"])


def main() -> None:
    args = parse_peer_args(__doc__.splitlines()[0])
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {ONE_THREAD}".strip()
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    try:
        from sbx import DQN
    except ImportError:
        raise SystemExit(
            "error: sbx-rl is not installed here; run this peer with the interpreter of "
            "runs/peer-venvs/sbx_dqn, which python -m benchmarks run --peers sbx_dqn makes"
        ) from None
    torch.set_num_threads(1)  # the protocol's evaluation envs and tensors
    train_with_zoo_settings("sbx_dqn", DQN, args, lambda run, m: run.watch(FlaxQValues(m.policy)))


if __name__ == "__main__":
    main()
