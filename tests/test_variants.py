"""Double DQN and the dueling head change the math they claim to change."""

from __future__ import annotations

import json

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import OneHot
from torchrl.modules import QValueActor

from trl_cartpole.config.schema import flat_fields, to_config
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.losses import make_dqn_loss
from trl_cartpole.parts.models import make_q_actor, make_q_network
from trl_cartpole.policy.load import evaluate_checkpoint
from trl_cartpole.run.training import train

from .conftest import SMOKE_OVERRIDES

W_ONLINE = [[1.0, 0.0], [0.0, 2.0]]  # Q_online(s') = [1, 2] at s' = [1, 1]: argmax is action 1
W_TARGET = [[3.0, 0.0], [0.0, 1.0]]  # Q_target(s') = [3, 1]: max is 3, but Q_target(s', 1) = 1


def _loss_with_disagreeing_networks(double_dqn: bool):
    net = nn.Linear(2, 2, bias=False)
    with torch.no_grad():
        net.weight.copy_(torch.tensor(W_TARGET))
    actor = QValueActor(net, in_keys=["observation"], spec=OneHot(2))
    loss = make_dqn_loss(actor, gamma=0.5, loss_function="l2", double_dqn=double_dqn)
    with torch.no_grad():  # the target network keeps W_TARGET; the online one moves on
        net.weight.copy_(torch.tensor(W_ONLINE))
    return loss


def _batch() -> TensorDict:
    # s = [3, 0], a = 0: Q_online(s, a) = 3; r = 1; s' = [1, 1]; not done.
    not_done = torch.zeros(1, 1, dtype=torch.bool)
    return TensorDict(
        {
            "observation": torch.tensor([[3.0, 0.0]]),
            "action": torch.tensor([[1, 0]]),
            "next": {
                "observation": torch.tensor([[1.0, 1.0]]),
                "reward": torch.ones(1, 1),
                "done": not_done,
                "terminated": not_done,
                "truncated": not_done,
            },
        },
        batch_size=[1],
    )


def test_double_dqn_target_uses_online_argmax_and_target_value():
    # Double: y = 1 + 0.5 * Q_target(s', argmax Q_online(s', .)) = 1 + 0.5 * 1 = 1.5 -> d = 1.5
    double = _loss_with_disagreeing_networks(double_dqn=True)(_batch())["loss"].item()
    assert double == pytest.approx(1.5**2)
    # Vanilla: y = 1 + 0.5 * max Q_target(s', .) = 2.5 -> d = 0.5
    vanilla = _loss_with_disagreeing_networks(double_dqn=False)(_batch())["loss"].item()
    assert vanilla == pytest.approx(0.5**2)


def test_dueling_head_is_value_plus_centred_advantage():
    torch.manual_seed(0)
    net = make_q_network(obs_dim=4, num_actions=3, num_cells=[16, 8], head="dueling")
    torso, head = net
    obs = torch.randn(6, 4)
    q = net(obs)  # [6, 3]
    features = torso(obs)  # [6, 8]
    value, advantage = head.value(features), head.advantage(features)  # [6, 1], [6, 3]
    assert torch.allclose(q, value + advantage - advantage.mean(-1, keepdim=True), atol=1e-6)
    # The advantage stream the head adds has zero mean per state, and Q - V is exactly it.
    _, centred = head.streams(features)  # [6, 1, 3]
    assert torch.allclose(centred.mean(-1), torch.zeros(6, 1), atol=1e-6)
    assert torch.allclose(q - value, centred.squeeze(-2), atol=1e-6)
    assert not torch.allclose(advantage.mean(-1), torch.zeros(6), atol=1e-3)  # raw one is not
    linears = [(m.in_features, m.out_features) for m in net.modules() if isinstance(m, nn.Linear)]
    assert linears == [(4, 16), (16, 8), (8, 1), (8, 3)]


def test_distributional_dueling_head_centres_the_advantage_per_atom():
    torch.manual_seed(0)
    net = make_q_network(4, num_actions=3, num_cells=[16], head="dueling", atoms=5)
    torso, head = net
    obs = torch.randn(6, 4)
    logits = net(obs)  # [6, 5, 3]
    assert logits.shape == (6, 5, 3)
    value = head.value(torso(obs)).unsqueeze(-1)  # [6, 5, 1]
    assert torch.allclose((logits - value).mean(-1), torch.zeros(6, 5), atol=1e-6)


def test_dueling_head_plugs_into_a_q_value_actor():
    env = make_env("CartPole-v1", seed=0)
    actor = make_q_actor(env.observation_spec, env.action_spec, head="dueling")
    td = actor(env.reset())
    assert td["action_value"].shape == torch.Size([2])
    assert td["action"].sum().item() == 1


RAINBOW = {
    "network.head": "dueling",
    "network.noisy": True,
    "exploration.schedule": "none",
    "network.distributional": True,
    "loss.double_dqn": True,
    "buffer.prioritized": True,
    # TorchRL's exponent on C51's cross-entropy priority (the default's 0.3 is on delta ** 2)
    "buffer.alpha": 0.6,
}
# What each preset changes relative to the default preset (configs/algo/dqn.yaml).
PRESET_CHANGES = {
    "double": {"loss.double_dqn": True},
    "dueling": {"network.head": "dueling"},
    "noisy": {"network.noisy": True, "exploration.schedule": "none"},
    "prioritized": {"buffer.prioritized": True},
    "nstep": {},  # the default preset already uses 3-step returns; nstep pins n = 3
    "c51": {"network.distributional": True, "loss.double_dqn": True},
    "rainbow": RAINBOW,
}


# the default tier trains the dueling preset (a head); the others in the slow tier
@pytest.mark.parametrize(
    "preset",
    [
        preset if preset == "dueling" else pytest.param(preset, marks=pytest.mark.slow)
        for preset in sorted(PRESET_CHANGES)
    ],
)
def test_variant_presets_switch_only_their_features_and_train(compose, tmp_path, preset):
    cfg = flat_fields(to_config(compose(f"algo={preset}", f"run_dir={tmp_path}")))
    default = flat_fields(to_config(compose(f"run_dir={tmp_path}")))
    changed = {key: cfg[key] for key in cfg if cfg[key] != default[key] and key != "algo.name"}
    assert changed == PRESET_CHANGES[preset]
    summary = train(compose(f"algo={preset}", *SMOKE_OVERRIDES, f"run_dir={tmp_path}"))
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["algo"] == preset == summary["algo"]
    assert written["frames"] == 300 and written["final_eval_episodes"] == 4
    assert written["updates"] > 0 and len(written["final_eval_returns"]) == 4
    # The best checkpoint rebuilds the preset's network from its stored config and plays.
    result, stored = evaluate_checkpoint(str(tmp_path / "checkpoints" / "best"), episodes=2)
    assert len(result.returns) == 2 and stored["algo"]["name"] == preset
