"""Noisy nets: noise is on in training and collection, off in evaluation, and resampled."""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torchrl.envs import ExplorationType, set_exploration_type
from torchrl.modules import NoisyLinear

from trl_cartpole.parts.collectors import make_collector
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.losses import make_dqn_loss
from trl_cartpole.parts.models import make_q_actor, reset_network_noise
from trl_cartpole.parts.optim import make_optimizer, make_update


def _noisy_actor(env):
    torch.manual_seed(0)
    return make_q_actor(env.observation_spec, env.action_spec, num_cells=[32, 32], noisy=True)


def _q(actor, obs: torch.Tensor, kind: ExplorationType) -> torch.Tensor:
    with set_exploration_type(kind):
        return actor(TensorDict(observation=obs, batch_size=obs.shape[:1]))["action_value"]


def _epsilons(actor) -> list[torch.Tensor]:
    return [m.weight_epsilon.clone() for m in actor.modules() if isinstance(m, NoisyLinear)]


def test_every_linear_layer_is_noisy():
    env = make_env("CartPole-v1", seed=0)
    layers = [m for m in _noisy_actor(env).modules() if isinstance(m, torch.nn.Linear)]
    assert len(layers) == 3 and all(isinstance(m, NoisyLinear) for m in layers)


def test_noise_is_on_in_training_off_in_evaluation_and_resampled():
    env = make_env("CartPole-v1", seed=0)
    actor = _noisy_actor(env)
    obs = torch.randn(5, 4)
    train_1 = _q(actor, obs, ExplorationType.RANDOM)  # [5, 2]
    eval_1 = _q(actor, obs, ExplorationType.DETERMINISTIC)
    reset_network_noise(actor)
    train_2 = _q(actor, obs, ExplorationType.RANDOM)
    eval_2 = _q(actor, obs, ExplorationType.DETERMINISTIC)
    assert not torch.allclose(train_1, eval_1, atol=1e-4)  # noise is active in training
    assert not torch.allclose(train_1, train_2, atol=1e-4)  # and differs once resampled
    assert torch.equal(eval_1, eval_2)  # evaluation uses the mean weights only


def _batch(n: int = 16) -> TensorDict:
    torch.manual_seed(1)
    flags = torch.zeros(n, 1, dtype=torch.bool)
    return TensorDict(
        {
            "observation": torch.randn(n, 4),
            "action": torch.nn.functional.one_hot(torch.randint(2, (n,)), 2),
            "next": {
                "observation": torch.randn(n, 4),
                "reward": torch.ones(n, 1),
                "done": flags,
                "terminated": flags,
                "truncated": flags,
            },
        },
        batch_size=[n],
    )


def test_update_trains_through_the_noise_and_resamples_it_after_each_step():
    env = make_env("CartPole-v1", seed=0)
    actor = _noisy_actor(env)
    loss = make_dqn_loss(actor, gamma=0.99)
    update = make_update(loss, make_optimizer(actor.parameters(), lr=1e-3), noisy_network=actor)
    batch = _batch()
    # TorchRL runs a loss under its deterministic_sampling_mode; the factory makes it RANDOM.
    assert loss.deterministic_sampling_mode is ExplorationType.RANDOM
    noisy_loss = loss(batch.clone())["loss"]
    loss.deterministic_sampling_mode = ExplorationType.DETERMINISTIC
    mean_loss = loss(batch.clone())["loss"]  # what TorchRL's default would have trained on
    loss.deterministic_sampling_mode = ExplorationType.RANDOM
    before = _epsilons(actor)
    first = update(batch.clone())
    after_first = _epsilons(actor)
    update(batch.clone())
    after_second = _epsilons(actor)
    assert torch.allclose(first["loss"], noisy_loss)  # the step saw the noisy network
    assert not torch.allclose(noisy_loss, mean_loss)
    for b, a1, a2 in zip(before, after_first, after_second, strict=True):
        assert not torch.equal(b, a1) and not torch.equal(a1, a2)  # new noise every update
    sigma = [m.weight_sigma for m in actor.modules() if isinstance(m, NoisyLinear)]
    assert all(s.grad is not None and s.grad.abs().sum() > 0 for s in sigma)  # sigma learns


def test_collector_acts_with_the_current_noise():
    env = make_env("CartPole-v1", seed=0)
    actor = _noisy_actor(env)
    collector = make_collector(
        env, actor, frames_per_batch=8, total_frames=16, init_random_frames=0
    )
    batches = iter(collector)
    for _ in range(2):
        batch = next(batches)  # [8]
        obs = batch["observation"]
        assert torch.allclose(batch["action_value"], _q(actor, obs, ExplorationType.RANDOM))
        assert not torch.allclose(
            batch["action_value"], _q(actor, obs, ExplorationType.DETERMINISTIC), atol=1e-4
        )
        reset_network_noise(actor)  # what the loop does after each batch
    collector.shutdown()
