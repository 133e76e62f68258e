"""SBX (Stable-Baselines3 in JAX) DQN with rl-zoo3's tuned settings, under the benchmark protocol.

    python -m benchmarks run --algos dqn --peers sbx_dqn --seeds 0 1 2
    runs/peer-venvs/sbx_dqn/bin/python -m benchmarks.peers.sbx_dqn --seed 0 \\
        --run-dir runs/peers/sbx_dqn-seed0               # one run, once that venv exists

``sbx-rl`` needs JAX, flax and optax, so it runs from a virtual environment of its own
(``benchmarks.harness.PEER_VENVS``), made on first use. Its ``DQN`` takes Stable-Baselines3's
arguments, so the settings (rl-zoo3 2.9.2's ``dqn.yml``), their rescaled exploration and the
protocol are :mod:`benchmarks.peers.sb3_dqn`'s. What SBX 0.28.0 does differently with them:
its Q-network is two hidden layers of ``net_arch[0]`` units (zoo's CartPole [256, 256] is
that; where zoo names none, SB3's default [64, 64] is passed; another shape is refused), it
clips no gradient (SB3 clips the norm at 10), and it
samples one batch of ``batch_size * gradient_steps`` transitions for each training call.

XLA's CPU client spreads its work over every core, and no flag of JAX 0.10 we tried holds it to
one thread (with ``--xla_cpu_multi_thread_eigen=false``, five threads still took CPU time in a
jit matrix product, as without it), so ``python -m benchmarks run`` pins this peer's process to
a core of its own (``benchmarks.harness.PINNED_PEERS``), as every other run's one torch thread
takes one core's work; run by hand, ``taskset -c 0`` does the same. The protocol evaluates and
keeps the flax network's parameters through :class:`FlaxQValues`.
"""

from __future__ import annotations

import os

import numpy as np
import torch

from benchmarks.peers.protocol import parse_peer_args
from benchmarks.peers.zoo_settings import train_with_zoo_settings

SB3_NET_ARCH = [64, 64]  # Stable-Baselines3's DQN network where policy_kwargs names none


class FlaxQValues(torch.nn.Module):
    """An SBX DQN's Q-network as the protocol reads a torch one: observations ``[E, obs]``
    float32 -> action values ``[E, A]`` (SBX's jitted ``qf.apply``); its ``state_dict`` holds
    the online parameters (JAX arrays, never changed in place), which ``load_state_dict`` puts
    back, the target network's left as they are."""

    def __init__(self, policy) -> None:
        super().__init__()
        self.policy = policy  # sbx.dqn.policies.DQNPolicy: its qf_state is replaced each update

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        values = self.policy.qf.apply(self.policy.qf_state.params, observations.numpy())
        return torch.from_numpy(np.array(values))  # [E, A], a copy torch may write to

    def state_dict(self, *args, **kwargs) -> dict:
        return {"params": self.policy.qf_state.params}

    def load_state_dict(self, state_dict: dict, *args, **kwargs) -> None:
        self.policy.qf_state = self.policy.qf_state.replace(params=state_dict["params"])


def main() -> None:
    args = parse_peer_args(__doc__.splitlines()[0])
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    try:
        from sbx import DQN
    except ImportError:
        raise SystemExit(
            "error: sbx-rl is not installed here; run this peer with the interpreter of "
            "runs/peer-venvs/sbx_dqn, which python -m benchmarks run --peers sbx_dqn makes"
        ) from None

    def sbx_dqn(policy: str, env_id: str, **settings):
        """SBX's DQN with zoo's network as SB3 builds it, or a one-line refusal."""
        net_arch = settings.setdefault("policy_kwargs", {}).setdefault("net_arch", SB3_NET_ARCH)
        if len(net_arch) != 2 or len(set(net_arch)) != 1:
            raise SystemExit(
                f"error: rl-zoo3's net_arch for {env_id} is {net_arch}; SBX's DQN network is two "
                "layers of net_arch[0] units, so this peer would not be zoo's: race another env"
            )
        return DQN(policy, env_id, **settings)

    torch.set_num_threads(1)  # the protocol's evaluation tensors
    train_with_zoo_settings(
        "sbx_dqn", sbx_dqn, args, lambda run, m: run.watch(FlaxQValues(m.policy))
    )


if __name__ == "__main__":
    main()
