"""n-step windows end where a trajectory ends, however TorchRL code hands the data over.

Every stored transition is checked against a reference computed by hand from the steps each
env took: R = sum_{j<k} gamma^j r_{t+j}, the next observation that of step t+k-1, with
k = min(n, steps to the episode's end, steps left in the env's row of the batch).
"""

from __future__ import annotations

import warnings

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.trainers.algorithms import DQNTrainer

from trl_cartpole.compat import held_steps, n_step_transform
from trl_cartpole.fast.n_step import WindowedNStepTransform, use_windowed_n_steps
from trl_cartpole.parts.collectors import make_collector
from trl_cartpole.parts.env import make_env
from trl_cartpole.parts.exploration import make_exploration
from trl_cartpole.parts.losses import make_dqn_loss, make_target_updater
from trl_cartpole.parts.models import make_q_actor
from trl_cartpole.parts.optim import make_optimizer
from trl_cartpole.parts.replay import (
    NStepTransform,
    leaves_of,
    make_replay_buffer,
    trajectory_ends,
)

N_STEPS, GAMMA = 3, 0.99


def expected_windows(rows: list[TensorDict], n: int, gamma: float) -> list[dict]:
    """The n-step transitions of each env's row ``[T]``, cut at the row's end and at each
    done (the reference, from the steps alone), in the order a flattened batch stores them."""
    out = []
    for row in rows:
        done = row["next", "done"].reshape(-1).tolist()
        reward = row["next", "reward"].reshape(-1).tolist()
        length = len(done)
        for t in range(length):
            k = 1
            while k < n and t + k < length and not done[t + k - 1]:
                k += 1
            out.append(
                {
                    "observation": row["observation"][t],
                    "step_count": int(row["step_count"][t]),
                    "k": k,
                    "reward": sum(gamma**j * reward[t + j] for j in range(k)),
                    "next_observation": row["next", "observation"][t + k - 1],
                    "next_step_count": int(row["next", "step_count"][t + k - 1]),
                    "terminated": bool(row["next", "terminated"][t + k - 1]),
                }
            )
    return out


def assert_stored_as_expected(stored: TensorDict, expected: list[dict]) -> None:
    assert stored.shape[0] == len(expected)
    for i, want in enumerate(expected):
        got = stored[i]
        where = f"transition {i}"
        assert torch.equal(got["observation"], want["observation"]), where
        assert int(got["step_count"]) == want["step_count"], where
        assert int(got["steps_to_next_obs"]) == want["k"], where
        assert float(got["next", "reward"]) == pytest.approx(want["reward"], rel=1e-6), where
        assert torch.equal(got["next", "observation"], want["next_observation"]), where
        # the window stays in one env's trajectory: its step count moves by the window's length
        assert int(got["next", "step_count"]) == want["next_step_count"], where
        assert want["next_step_count"] - want["step_count"] == want["k"], where
        assert bool(got["next", "terminated"]) == want["terminated"], where


@pytest.mark.parametrize("prioritized", [False, True], ids=["uniform", "prioritized"])
def test_torchrls_dqn_trainer_with_a_4_env_collector_stores_windows_that_stay_in_one_env(
    prioritized,
):
    torch.manual_seed(0)
    env = make_env("CartPole-v1", seed=0, num_envs=4)
    actor = make_q_actor(env.observation_spec, env.action_spec)
    exploration = make_exploration(env.action_spec, eps_end=0.05, annealing_num_steps=200)
    collector = make_collector(
        env,
        TensorDictSequential(actor, exploration),
        frames_per_batch=32,
        total_frames=640,
        init_random_frames=0,
    )
    buffer = make_replay_buffer(
        max_size=10_000,
        batch_size=16,
        n_steps=N_STEPS,
        gamma=GAMMA,
        prioritized=prioritized,
        **({"alpha": 0.6, "beta": 0.4} if prioritized else {}),
    )
    loss = make_dqn_loss(actor, replay_buffer=buffer)
    collected: list[TensorDict] = []
    with warnings.catch_warnings():  # DQNTrainer says it is a prototype
        warnings.simplefilter("ignore")
        trainer = DQNTrainer(
            collector=collector,
            total_frames=640,
            frame_skip=1,
            optim_steps_per_batch=1,
            loss_module=loss,
            optimizer=make_optimizer(actor.parameters()),
            replay_buffer=buffer,
            target_net_updater=make_target_updater(loss, tau=0.05),
            greedy_module=exploration,
            progress_bar=False,
            logger=None,
            enable_logging=False,
            save_trainer_file=None,
        )
        trainer.register_op("pre_epoch", lambda batch: collected.append(batch.clone()) or batch)
        trainer.train()
    collector.shutdown()
    # the trainer hands on the batch it stored: [4, 8] flattened env by env to [32]
    assert len(collected) == 20 and collected[0].shape == (32,)
    collected = [batch.reshape(4, 8) for batch in collected]
    # the trainer marks every step truncated before flattening: not an episode end
    assert bool(collected[0]["next", "truncated"].all())
    rows = [batch[e] for batch in collected for e in range(4)]
    expected = expected_windows(rows, N_STEPS, GAMMA)[:-N_STEPS]  # the last 3: held back
    assert_stored_as_expected(buffer[:], expected)
    assert sum(w["k"] == N_STEPS for w in expected) > len(expected) // 2  # windows of 3 kept


def _rollout(env, steps: int) -> TensorDict:
    torch.manual_seed(steps)  # the rollout's random actions
    return env.rollout(steps, break_when_any_done=False)


def test_a_flattened_batch_stores_the_windows_of_each_env_extended_one_at_a_time():
    vector = make_env("CartPole-v1", seed=0, num_envs=3)
    rollout = _rollout(vector, 20)  # [3, 20]
    vector.close()
    flattened = make_replay_buffer(max_size=1_000, n_steps=N_STEPS, gamma=GAMMA)
    flattened.extend(rollout.reshape(-1))  # as TorchRL's trainers store a batch
    one_at_a_time = make_replay_buffer(max_size=1_000, n_steps=N_STEPS, gamma=GAMMA)
    for e in range(3):
        one_at_a_time.extend(rollout[e])
    expected = expected_windows([rollout[e] for e in range(3)], N_STEPS, GAMMA)[:-N_STEPS]
    assert_stored_as_expected(flattened[:], expected)
    assert_stored_as_expected(one_at_a_time[:], expected)
    # as collected, [envs, T]: each env's windows continue into its next batch
    as_collected = make_replay_buffer(max_size=1_000, n_steps=N_STEPS, gamma=GAMMA)
    as_collected.extend(rollout)
    assert len(as_collected) == 3 * (20 - N_STEPS)


def test_a_second_rollout_after_a_reset_starts_new_windows():
    env = make_env("CartPole-v1", seed=0)
    first, second = _rollout(env, 12), _rollout(env, 12)  # each starts with a reset
    env.close()
    assert int(second["step_count"][0]) == 0
    buffer = make_replay_buffer(max_size=1_000, n_steps=N_STEPS, gamma=GAMMA)
    buffer.extend(first)
    buffer.extend(second)
    expected = expected_windows([first, second], N_STEPS, GAMMA)[:-N_STEPS]
    assert_stored_as_expected(buffer[:], expected)


def test_trajectory_ends_reads_done_resets_and_seams_not_a_truncated_mark():
    env = make_env("CartPole-v1", seed=0, num_envs=2)
    rollout = _rollout(env, 6)  # [2, 6]
    env.close()
    flat = rollout.reshape(-1).clone()  # env 1's first step follows env 0's last
    flat["next", "done"].zero_()
    flat["next", "truncated"].fill_(True)  # TorchRL's trainers' mark on every step
    ends = trajectory_ends(flat).reshape(-1).tolist()
    assert ends == [False] * 5 + [True] + [False] * 6  # the seam; the last step: not known
    flat["next", "done"][2] = True
    assert trajectory_ends(flat).reshape(-1).nonzero().reshape(-1).tolist() == [2, 5]


def test_trajectory_ends_reads_a_new_trajectory_id_where_the_observations_match():
    observation = torch.zeros(5, 1)  # every observation alike: only the ids tell the seam
    steps = TensorDict(
        {
            "observation": observation,
            "collector": {"traj_ids": torch.tensor([7, 7, 8, 8, 8])},
            "next": {"observation": observation, "done": torch.zeros(5, 1, dtype=torch.bool)},
        },
        batch_size=[5],
    )
    assert trajectory_ends(steps).reshape(-1).tolist() == [False, True, False, False, False]


def test_data_that_cannot_tell_trajectories_apart_is_refused_in_one_line():
    steps = TensorDict(
        {
            "action": torch.zeros(6, 1),
            "next": {"reward": torch.ones(6, 1), "done": torch.zeros(6, 1, dtype=torch.bool)},
        },
        batch_size=[6],
    )
    buffer = make_replay_buffer(max_size=100, n_steps=N_STEPS, gamma=GAMMA)
    with pytest.raises(ValueError, match=r"cannot be told; extend with batches as") as error:
        buffer.extend(steps)
    assert "\n" not in str(error.value)
    assert len(buffer) == 0


def windowed(buffer):
    """``buffer`` with its n-step windows built on tensors (``fast=true``'s)."""
    use_windowed_n_steps(buffer)
    assert type(n_step_transform(buffer)) is WindowedNStepTransform
    return buffer


def _steps(envs: int, length: int, generator: torch.Generator, extra: bool) -> TensorDict:
    """``[envs, length]`` steps of counter envs: the observation counts the steps of the
    episode, an episode ends at random (a termination or a truncation), a new one starts at 0."""
    done = torch.rand(envs, length, 1, generator=generator) < 0.2
    terminated = done & (torch.rand(envs, length, 1, generator=generator) < 0.5)
    count = torch.zeros(envs, length + 1, 1)
    for t in range(length):
        count[:, t + 1] = torch.where(done[:, t], 0.0, count[:, t] + 1)
    observation = count[:, :-1].expand(envs, length, 3) + torch.rand(envs, length, 3)
    steps = TensorDict(
        {
            "observation": observation,
            "action": torch.randint(0, 4, (envs, length, 1), generator=generator),
            "next": {
                "observation": observation.roll(-1, 1),  # [.., t] = step t + 1's
                "reward": torch.randn(envs, length, 1, generator=generator),
                "done": done,
                "terminated": terminated,
                "truncated": done & ~terminated,
            },
        },
        batch_size=[envs, length],
    )
    steps["next", "observation"][:, -1] = torch.rand(envs, 3)
    if extra:  # an Atari game's end of life under "next", and the collector's trajectory ids
        steps["next", "end-of-life"] = torch.rand(envs, length, 1, generator=generator) < 0.1
        steps["collector", "traj_ids"] = done.squeeze(-1).cumsum(-1)
    return steps


@pytest.mark.parametrize(
    ("batches", "n_steps"),
    [
        ([(4, 1)] * 12, 3),  # the default's 32 envs, one step each, in miniature
        ([(2, 5), (2, 1), (2, 2), (2, 7)], 3),
        ([(3, 8)] * 3, 10),  # windows longer than a batch
        ([(1, 6)] * 4, 2),
    ],
)
@pytest.mark.parametrize("extra", [False, True], ids=["plain", "atari-entries"])
@pytest.mark.parametrize("layout", ["as-collected", "flattened", "one-env"])
def test_the_windows_built_on_tensors_store_bitwise_what_torchrls_transform_stores(
    batches, n_steps, extra, layout
):
    generator = torch.Generator().manual_seed(n_steps + len(batches))
    ours = windowed(make_replay_buffer(max_size=1_000, n_steps=n_steps, gamma=GAMMA))
    stock = make_replay_buffer(max_size=1_000, n_steps=n_steps, gamma=GAMMA)
    for envs, length in batches:
        steps = _steps(envs, length, generator, extra)
        if layout == "flattened":  # as TorchRL's trainers extend: every step marked truncated
            steps = steps.reshape(-1)
            steps["next", "truncated"].fill_(True)
        elif layout == "one-env":
            steps = steps[0]
        ours.extend(steps.clone())
        stock.extend(steps.clone())
    assert len(ours) == len(stock) > 0
    got, want = ours.storage[: len(ours)], stock.storage[: len(stock)]
    assert set(got.keys(True, True)) == set(want.keys(True, True))
    for key in want.keys(True, True):
        assert got[key].dtype == want[key].dtype, key
        assert torch.equal(got[key], want[key]), key
    held, held_stock = (held_steps(n_step_transform(b)) for b in (ours, stock))
    assert held.batch_size == held_stock.batch_size
    assert set(held.keys(True, True)) == set(held_stock.keys(True, True))
    for key in held_stock.keys(True, True):
        assert torch.equal(held[key], held_stock[key]), key


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU here")
def test_the_windows_built_on_tensors_match_torchrls_on_a_gpu():
    generator = torch.Generator().manual_seed(1)
    device = torch.device("cuda")
    ours = windowed(make_replay_buffer(max_size=100, n_steps=N_STEPS, gamma=GAMMA, device=device))
    stock = make_replay_buffer(max_size=100, n_steps=N_STEPS, gamma=GAMMA, device=device)
    for _ in range(3):
        steps = _steps(2, 4, generator, extra=True).to(device)
        ours.extend(steps.clone())
        stock.extend(steps.clone())
    got, want = ours.storage[: len(ours)], stock.storage[: len(stock)]
    assert len(ours) == len(stock) > 0
    for key in want.keys(True, True):
        assert got[key].device.type == "cuda" and torch.equal(got[key], want[key]), key


def test_a_batch_the_tensor_windows_do_not_cover_is_stored_by_torchrls_transform():
    generator = torch.Generator().manual_seed(0)
    steps = _steps(2, 6, generator, extra=False)
    steps["mask"] = torch.ones(2, 6, dtype=torch.bool)  # MultiStepTransform's own mask entry
    transform = WindowedNStepTransform(N_STEPS, GAMMA)
    assert not transform._windows_apply(leaves_of(steps), None)
    buffer = make_replay_buffer(max_size=100, transform=transform)
    stock = make_replay_buffer(max_size=100, transform=NStepTransform(N_STEPS, GAMMA))
    buffer.extend(steps.clone())
    stock.extend(steps.clone())
    assert torch.equal(buffer.storage[:6]["next", "reward"], stock.storage[:6]["next", "reward"])
