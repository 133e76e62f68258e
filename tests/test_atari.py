"""Atari games: the preprocessing against Gymnasium's frame by frame, the learner's view, frames
stored once, the config's refusals, and a short Breakout run exported to a plain Gymnasium
loop."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.envs.utils import step_mdp

from tests.conftest import run_script_in_process
from trl_cartpole.compat import gym_env
from trl_cartpole.config.schema import to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.envs.atari import EOL_KEY, LearnerView, make_atari_env
from trl_cartpole.envs.ids import register_atari_games
from trl_cartpole.errors import ConfigError
from trl_cartpole.parts.replay import make_replay_buffer
from trl_cartpole.storage.frames import FrameStackStorage

pytest.importorskip("ale_py")
pytest.importorskip("cv2")

BREAKOUT = "ALE/Breakout-v5"


def _deterministic_pair(seed: int):
    """Breakout through this project's preprocessing and through Gymnasium's own
    (``AtariPreprocessing`` + ``FrameStackObservation(4)``), with no NOOPs, no FIRE and no
    sticky actions: both sides deterministic. Returns (our env, its reset state, Gymnasium's
    env, its first observation)."""
    from gymnasium.wrappers import AtariPreprocessing, FrameStackObservation

    ours = make_atari_env(
        BREAKOUT,
        seed=seed,
        repeat_action_probability=0.0,
        preprocessing={"noop_max": 0, "fire_on_reset": False},
    )
    register_atari_games()
    base = gym.make(BREAKOUT, frameskip=1, repeat_action_probability=0.0)
    theirs = FrameStackObservation(AtariPreprocessing(base, noop_max=0), 4)
    observation, _ = theirs.reset(seed=seed)
    return ours, ours.reset(), theirs, observation


def test_the_preprocessing_gives_gymnasiums_frames_rewards_and_ends():
    """Both sides deterministic (:func:`_deterministic_pair`): the same actions must give the
    same [4, 84, 84] stacks (the max of two frames, INTER_AREA, the reset stack)."""
    env, state, theirs, expected = _deterministic_pair(3)
    actions = np.random.default_rng(0).integers(4, size=400)
    ends = 0
    for step, action in enumerate(actions.tolist()):
        assert np.array_equal(state["pixels"].numpy(), expected), f"step {step}"
        state["action"] = torch.tensor(action)
        state = env.step(state)
        expected, reward, terminated, truncated, _ = theirs.step(action)
        assert float(state["next", "reward"]) == reward, f"step {step}"
        assert bool(state["next", "terminated"]) == terminated, f"step {step}"
        if terminated or truncated:
            ends += 1
            expected, _ = theirs.reset(seed=step)
            env.set_seed(step)
            state = env.reset()
        else:
            state = step_mdp(state)
    assert state["pixels"].shape == (4, 84, 84) and state["pixels"].dtype == torch.uint8
    assert ends >= 1  # a game ended on the way (the last life lost to random play)


def test_noop_starts_and_fire_count_their_frames():
    """After a reset: 1 to noop_max NOOP frames (drawn from the game's seeded RNG), then two
    FIRE steps, each held for the frame skip (4)."""
    counts = set()
    for seed in range(6):
        env = make_atari_env(BREAKOUT, seed=seed, preprocessing={"noop_max": 5})
        env.reset()
        ale = gym_env(env).unwrapped.ale
        counts.add(ale.getEpisodeFrameNumber() - 2 * 4)
        env.close()
    assert counts <= set(range(1, 6)) and len(counts) > 1


def test_a_lost_life_is_followed_by_fire_steps_fire_steps_in_the_same_step():
    """``fire_steps`` FIRE steps of 4 frames after the reset and inside the step that loses a
    life: the next state the policy sees is the served game's."""
    env = make_atari_env(
        BREAKOUT,
        seed=0,
        repeat_action_probability=0.0,
        preprocessing={"noop_max": 0, "fire_steps": 3},
    )
    state = env.reset()
    ale = gym_env(env).unwrapped.ale
    assert ale.getEpisodeFrameNumber() == 3 * 4
    jumps = []
    for _ in range(2000):
        state["action"] = torch.tensor(0)  # NOOP: the paddle stays, the served ball is lost
        before = ale.getEpisodeFrameNumber()
        stepped = env.step(state)
        jumps.append((ale.getEpisodeFrameNumber() - before, bool(stepped["next", EOL_KEY])))
        if stepped["next", EOL_KEY]:
            break
        state = step_mdp(stepped)
    assert jumps[-1] == (4 + 3 * 4, True)  # the lost life's step, then three FIRE steps
    assert {jump for jump, _ in jumps[:-1]} == {4}
    with pytest.raises(ValueError, match="steps=0 must be >= 1"):
        make_atari_env(BREAKOUT, preprocessing={"fire_steps": 0})


def test_a_lost_life_fires_again_and_the_game_goes_on():
    """A lost life marks end-of-life, not done; the episode's return is the game's score."""
    env = make_atari_env(BREAKOUT, seed=0, repeat_action_probability=0.0)
    torch.manual_seed(0)
    rollout = env.rollout(3000, break_when_any_done=True)  # random play to the game's end
    lost = rollout["next", EOL_KEY].squeeze(-1)
    done = rollout["next", "done"].squeeze(-1)
    assert done[-1] and not done[:-1].any()
    assert int(lost.sum()) == 5  # Breakout's five lives, the last one with the game
    score = rollout["next", "reward"].sum()
    assert float(rollout["next", "episode_reward"][-1]) == float(score)


def test_the_learner_view_ends_episodes_at_a_lost_life_and_clips_rewards():
    batch = TensorDict(
        {
            "next": {
                "reward": torch.tensor([[4.0], [0.0], [-2.0]]),
                "terminated": torch.tensor([[False], [False], [True]]),
                "done": torch.tensor([[False], [False], [True]]),
                EOL_KEY: torch.tensor([[True], [False], [True]]),
            }
        },
        batch_size=[3],
    )
    seen = LearnerView()._inv_call(batch)
    assert seen["next", "reward"].squeeze(-1).tolist() == [1.0, 0.0, -1.0]
    assert seen["next", "terminated"].squeeze(-1).tolist() == [True, False, True]
    assert seen["next", "done"].squeeze(-1).tolist() == [True, False, True]
    assert batch["next", "reward"][0].item() == 4.0  # the env's data is left as it was
    kept = LearnerView(life_loss_ends=False, clip_rewards=False)._inv_call(batch)
    assert kept["next", "terminated"].squeeze(-1).tolist() == [False, False, True]
    assert kept["next", "reward"].squeeze(-1).tolist() == [4.0, 0.0, -2.0]


def _breakout_transitions(steps: int) -> TensorDict:
    """[2, steps] steps of two Breakout games (SerialEnv-like stacking of two rollouts)."""
    keys = ["pixels", "action", ("next", "pixels"), ("next", "reward"), ("next", "done")]
    keys += [("next", "terminated"), ("next", "truncated"), ("next", "step_count"), "step_count"]
    games = []
    for seed in (0, 1):
        env = make_atari_env(BREAKOUT, seed=seed)
        torch.manual_seed(seed)
        games.append(env.rollout(steps, break_when_any_done=False).select(*keys))
        env.close()
    return torch.stack(games)  # [2, steps]


def test_frames_stored_once_give_back_what_was_stored_after_wrapping_around():
    data = _breakout_transitions(160)
    plain = make_replay_buffer(max_size=200, batch_size=16, n_steps=3, gamma=0.99)
    once = make_replay_buffer(storage=FrameStackStorage(200), batch_size=16, n_steps=3, gamma=0.99)
    for chunk in data.split(40, dim=1):  # [2, 40] batches, as a collector of 2 envs gives
        plain.extend(chunk)
        once.extend(chunk)
    assert len(plain) == len(once) == 200  # wrapped around: 2 x 160 windows into 200 rows
    rows = torch.arange(200)
    stored, given = plain.storage.get(rows), once.storage.get(rows)
    assert set(stored.keys(True, True)) == set(given.keys(True, True))
    for key in stored.keys(True, True):
        assert torch.equal(stored[key], given[key]), key
    pool = once.storage.pool
    # each row adds one new frame (its next stack's newest); game starts add their stacks
    assert 200 <= pool.held <= 200 + 3 * 4 + 2 * 4
    assert int(pool.uses.sum()) == 200 * 2 * 4  # every row's 8 slots counted, the old released
    with tempfile.TemporaryDirectory() as folder:
        once.dumps(folder)
        again = make_replay_buffer(
            storage=FrameStackStorage(200), batch_size=16, n_steps=3, gamma=0.99
        )
        again.loads(folder)
        loaded = again.storage.get(rows)
        assert all(torch.equal(loaded[k], given[k]) for k in given.keys(True, True))
        assert again.storage.pool.held == pool.held


def test_frames_stored_once_find_equal_frames_by_their_bytes():
    """Stacks of arbitrary frames, repeated and shuffled: the pool holds each distinct frame
    once, however the stacks are laid out."""
    frames = torch.randint(0, 256, (5, 6, 6), dtype=torch.uint8)
    order = torch.tensor([[0, 1, 2, 3], [1, 2, 3, 4], [4, 4, 4, 4], [0, 0, 1, 1]])
    data = TensorDict(
        {"pixels": frames[order], "next": {"pixels": frames[order.flip(-1)]}}, batch_size=[4]
    )
    storage = FrameStackStorage(4)
    storage.set(torch.arange(4), data)
    assert storage.pool.held == 5
    assert torch.equal(storage.get(torch.tensor([2, 0]))["pixels"], frames[order[[2, 0]]])
    storage.set(torch.arange(4), data[[2, 2, 2, 2]])  # overwrite all: only frame 4 still used
    assert storage.pool.held == 1


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ([f"env.id={BREAKOUT}"], r"is an Atari game.*env=breakout.*network.torso=cnn"),
        (["env=breakout", "env.make_kwargs.frameskip=4"], "env.atari.frame_skip instead"),
        (["env=breakout", "env.atari.frame_skip=0"], "frame_skip=0 must be >= 1"),
        (["buffer.storage=frames"], "buffer.storage=frames .* this run has none"),
    ],
)
def test_impossible_atari_configs_are_refused(compose, overrides, message):
    with pytest.raises(ConfigError, match=message):
        validate(to_config(compose(*overrides)))


def test_an_atari_run_is_named_without_the_namespace_slash(compose):
    cfg = compose("env=breakout", "seed=7")
    name = Path(str(cfg.run_dir))
    assert name.parent == Path("runs") and name.name.startswith("ALE-Breakout-v5-dqn-seed7-")


def test_the_preset_is_the_sixth_form_of_the_recipe_as_docs_atari_names_it(compose):
    """``env=breakout`` alone trains the form whose seeds docs/atari.md records: the same
    configuration as its named command's overrides, 2 hours of training that end the run before
    its 300 000 steps, and a learning rate that tapers from 1e-4 to 1e-5 at 135 000 steps (half
    way: 1e-4 - 0.5 x 9e-5 = 5.5e-5), then holds. Its update's number type is the machine's
    (``auto``: the named seeds' bfloat16 where the CPU computes it)."""
    from trl_cartpole.parts.optim import tapered_lr

    named = (
        "optim.lr_end=1e-5",
        "optim.lr_decay_frames=135000",
        "collector.total_frames=300000",
    )
    run = ("env=breakout", "seed=115", "run_dir=run")  # a fixed name: the default holds the time
    preset = to_config(compose(*run))
    assert preset == to_config(compose(*run, *named))
    assert (preset.collector.total_frames, preset.collector.max_train_seconds) == (300_000, 7200)
    optim = preset.optim
    assert (optim.lr, optim.lr_end, optim.autocast) == (1e-4, 1e-5, "auto")
    assert tapered_lr(optim.lr, optim.lr_end, 67_500, optim.lr_decay_frames) == pytest.approx(
        5.5e-5
    )
    assert tapered_lr(optim.lr, optim.lr_end, 200_000, optim.lr_decay_frames) == pytest.approx(1e-5)


def test_without_ale_py_the_message_names_the_atari_extra(monkeypatch):
    import importlib

    real = importlib.import_module

    def no_ale(name, *args, **kwargs):
        if name == "ale_py":
            raise ImportError("No module named 'ale_py'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(importlib, "import_module", no_ale)
    with pytest.raises(ConfigError, match=r"atari extra .* install it with .*\[atari\]"):
        register_atari_games()


def test_the_preset_sees_stacked_screens_and_stores_them_once(compose):
    from trl_cartpole.run.from_config import build_actor, build_env, build_replay_buffer
    from trl_cartpole.run.resources import run_memory_need

    cfg = validate(to_config(compose("env=breakout")))
    env = build_env(cfg, seed=0)
    assert env.observation_spec["pixels"].shape == (4, 84, 84)
    actor = build_actor(cfg, env)
    assert actor(env.reset())["action_value"].shape == (4,)  # Breakout's 4 actions
    assert isinstance(build_replay_buffer(cfg).storage, FrameStackStorage)
    need = run_memory_need(cfg, env)
    # 100 000 transitions: about one 84x84 frame each (and an eighth more), not 2 x 4
    assert 0.7e9 < need.buffer_bytes < 1.0e9
    env.close()


def test_a_batch_of_games_gets_an_action_per_game_and_its_state_read_after_it_closes(compose):
    # env.num_envs=2: a SerialEnv of games, whose action spec is batched ([2] indices); the
    # actor checks each game's action against one game's spec (it refused the batch before).
    from trl_cartpole.run.from_config import build_actor, build_env, build_exploration
    from trl_cartpole.store.env_state import env_snapshot

    cfg = validate(to_config(compose("env=breakout", "env.num_envs=2")))
    env = build_env(cfg, seed=0)
    actor = build_actor(cfg, env)
    step = actor(env.reset())
    assert step["action_value"].shape == (2, 4) and step["action"].shape == (2,)
    policy = TensorDictSequential(actor, build_exploration(cfg, env))  # epsilon 1 at first
    torch.manual_seed(0)
    drawn = torch.stack([policy(env.reset())["action"] for _ in range(20)])  # [20, 2]
    assert not torch.equal(drawn[:, 0], drawn[:, 1])  # an action drawn for each game
    assert len(env_snapshot(env)["atari"]) == 2
    env.close()
    assert env_snapshot(env) is None  # a closed batch holds no games (it recursed before)


TINY_BREAKOUT = [
    "env=breakout",
    "collector.total_frames=400",
    "collector.init_random_frames=300",
    "eval.interval_frames=200",
    "eval.episodes=1",
    "eval.final_episodes=1",
    "eval.candidates=1",
    "buffer.max_size=1000",
    "logger.plots=false",
    "logger.progress_bar=false",
]


@pytest.mark.slow  # a short Breakout run, exported and played in a plain Gymnasium loop
def test_an_exported_breakout_policy_plays_gymnasiums_own_preprocessing_alike(tmp_path):
    from trl_cartpole.policy.load import load_trained_policy

    run_dir = tmp_path / "run"
    proc = run_script_in_process("train.py", *TINY_BREAKOUT, f"run_dir={run_dir}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["frames"] == 400 and summary["updates"] > 0
    program = tmp_path / "policy.pt2"
    written = run_script_in_process("export.py", f"checkpoint={run_dir}", f"output={program}")
    assert written.returncode == 0, written.stderr[-2000:]
    assert "pixels [batch, 4, 84, 84] uint8" in written.stdout
    exported = torch.export.load(program).module()
    # Gymnasium's preprocessing and ours, deterministic: the greedy actions must agree.
    trained = load_trained_policy(run_dir)
    ours, state, theirs, observation = _deterministic_pair(5)
    for _ in range(200):
        values = exported(torch.from_numpy(observation)[None])  # [1, 4]
        action = int(values.argmax(-1))
        mine = trained.actor(state.select("pixels"))["action_value"]
        assert torch.allclose(values[0], mine, atol=1e-5)
        observation, _, terminated, truncated, _ = theirs.step(action)
        state["action"] = torch.tensor(action)
        state = step_mdp(ours.step(state))
        if terminated or truncated:
            break
    trained.env.close()


def test_a_restored_game_plays_on_exactly_as_the_saved_one():
    """The env's snapshot (ALE's state with the RNG of its sticky actions, the game's RNG of the
    NOOP starts, the stacked frames, the lives at the last step) and the carried step: a game
    restored into a fresh env gives the same frames, rewards, lives and ends as the saved one,
    step by step, through a lost life and a new game."""
    from trl_cartpole.store.env_state import env_snapshot, restore_env_snapshot

    torch.manual_seed(0)
    saved = make_atari_env(BREAKOUT, seed=0)  # sticky actions 0.25, NOOPs, FIRE: the preset's
    state = saved.reset()
    actions = np.random.default_rng(0).integers(4, size=340).tolist()
    for action in actions[:40]:
        state["action"] = torch.tensor(action)
        state = step_mdp(saved.step(state))
    snapshot = env_snapshot(saved)
    carried = state.clone()
    expected, saved_resets = [], []
    for action in actions[40:]:
        state["action"] = torch.tensor(action)
        stepped = saved.step(state)
        expected.append(stepped["next"].clone())
        state = step_mdp(stepped)
        if stepped["next", "done"]:  # a new game: its NOOP count from the game's own RNG
            state = saved.reset()
            saved_resets.append(state.clone())
    restored = make_atari_env(BREAKOUT, seed=9)
    restored.reset()
    torch.manual_seed(123)  # nothing of the game follows the torch RNG
    assert restore_env_snapshot(restored, snapshot)
    state, lost = carried, 0
    for step, action in enumerate(actions[40:]):
        state["action"] = torch.tensor(action)
        stepped = restored.step(state)
        for key in ("pixels", "reward", "done", EOL_KEY, "lives", "step_count"):
            assert torch.equal(stepped["next", key], expected[step][key]), (step, key)
        lost += int(stepped["next", EOL_KEY])
        state = step_mdp(stepped)
        if stepped["next", "done"]:
            state = restored.reset()
            expected_reset = saved_resets.pop(0)
            assert torch.equal(state["pixels"], expected_reset["pixels"])
    assert lost >= 1  # the game went through a lost life (and its FIRE) after the restore


def test_the_buffer_ends_an_n_step_window_at_a_lost_life_and_clips_its_rewards(compose):
    """The preset's buffer: LearnerView folds a lost life into the window's end before the
    n-step returns are formed, so a window stops at the lost life and does not bootstrap."""
    from trl_cartpole.run.from_config import build_replay_buffer

    cfg = validate(to_config(compose("env=breakout", "buffer.storage=memory")))
    buffer = build_replay_buffer(cfg)  # 10-step returns, gamma 0.99
    steps = 14
    pixels = torch.arange(steps + 1, dtype=torch.uint8)[:, None, None, None].expand(-1, 4, 2, 2)
    lost = torch.zeros(steps, 1, dtype=torch.bool)
    lost[2] = True  # a life lost at the third step; the game goes on
    batch = TensorDict(
        {
            "pixels": pixels[:-1],
            "action": torch.zeros(steps, dtype=torch.int64),
            "next": {
                "pixels": pixels[1:],
                "reward": torch.full((steps, 1), 3.0),
                "done": torch.zeros(steps, 1, dtype=torch.bool),
                "terminated": torch.zeros(steps, 1, dtype=torch.bool),
                "truncated": torch.zeros(steps, 1, dtype=torch.bool),
                EOL_KEY: lost,
            },
        },
        batch_size=[steps],
    )
    buffer.extend(batch)  # one game of 14 steps: the windows of the first 4 are complete
    first = buffer.storage.get(torch.arange(len(buffer)))
    assert len(buffer) == steps - 10
    # step 0's window: rewards 1 (clipped from 3) at steps 0, 1, 2, ending at the lost life
    assert first["steps_to_next_obs"][:3].flatten().tolist() == [3, 2, 1]
    assert torch.allclose(first["next", "reward"][0], torch.tensor([1 + 0.99 + 0.99**2]))
    assert first["next", "terminated"][:3].all()  # no bootstrap past the lost life
    assert not first["next", "terminated"][3]  # step 3's window starts after it
    assert int(first["next", "pixels"][0, -1, 0, 0]) == 3  # ends on the lost life's frame


def test_frames_stored_once_take_single_adds_refuse_rows_written_twice_and_empty():
    frames = torch.randint(0, 256, (6, 3, 3), dtype=torch.uint8)
    buffer = make_replay_buffer(storage=FrameStackStorage(3), batch_size=2)
    for i in range(4):  # buffer.add: an int cursor, wrapping around the 3 rows
        stacks = frames[[i, i + 1]]  # [2, 3, 3]
        buffer.add(TensorDict({"pixels": stacks, "next": {"pixels": frames[[i + 1, i + 2]]}}))
    rows = buffer.storage.get(torch.arange(3))
    assert torch.equal(rows["pixels"][0], frames[[3, 4]])  # row 0 rewritten by the 4th add
    assert buffer.storage.pool.held == 5  # frames 1 to 5 in use: frame 0 was released
    with pytest.raises(ValueError, match="writes some of the 3 rows twice"):
        buffer.storage.set(torch.tensor([0, 0]), buffer.storage.get(torch.tensor([1, 2])))
    buffer.empty()
    assert len(buffer) == 0 and buffer.storage.pool is None


def test_a_restored_game_repeats_the_saved_games_last_action_on_a_sticky_frame():
    """ALE's state leaves out the action a sticky frame repeats (the last frame's): the snapshot
    keeps it, so a game restored into an env that last did something else plays on as saved.
    Boxing, 64 points of one game, each restored into an env whose last action was another, 3
    steps on (12 frames): without the last action kept, 61 of 300 such points went apart; with
    it put back by one frame (itself sticky), 17 of 300."""
    from trl_cartpole.store.env_state import env_snapshot, restore_env_snapshot

    boxing = "ALE/Boxing-v5"
    saved = make_atari_env(boxing, seed=0)  # sticky actions 0.25, as Gymnasium makes it
    restored = make_atari_env(boxing, seed=9)
    state, actions = saved.reset(), np.random.default_rng(1).integers(18, size=1000).tolist()
    step = 0
    for _ in range(64):
        for _ in range(8):
            state["action"] = torch.tensor(actions[step])
            state, step = step_mdp(saved.step(state)), step + 1
        snapshot, carried = env_snapshot(saved), state.clone()
        other = restored.reset()  # the restored env's last action: another one
        other["action"] = torch.tensor((actions[step] + 1) % 18)
        restored.step(other)
        assert restore_env_snapshot(restored, snapshot)
        ours, theirs = carried.clone(), carried
        for k in range(3):
            ours["action"] = theirs["action"] = torch.tensor(actions[step + k])
            a, b = saved.step(theirs), restored.step(ours)
            assert torch.equal(a["next", "pixels"], b["next", "pixels"]), k
            rams = [gym_env(env).unwrapped.ale.getRAM() for env in (saved, restored)]
            assert np.array_equal(*rams), k  # the game's memory, not only its picture
            theirs, ours = step_mdp(a), step_mdp(b)
        assert restore_env_snapshot(saved, snapshot)  # back, and on from there
        state = carried


def test_make_env_answers_an_atari_id_with_the_factory_that_preprocesses_it():
    from trl_cartpole.parts.env import make_env

    with pytest.raises(ConfigError, match=r"Atari game: make_atari_env\('ALE/Breakout-v5'\)"):
        make_env(BREAKOUT)
    env = make_atari_env(BREAKOUT, seed=0)  # the factory it names builds it
    assert env.reset()["pixels"].shape == (4, 84, 84)
    env.close()
