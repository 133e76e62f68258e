"""CartPole from pixels (env=cartpole_pixels): TorchRL's pixel transforms and a CNN torso."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace

import pytest
import torch
from tensordict import TensorDict

from tests.conftest import run_script_in_process
from trl_cartpole.config.schema import to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.envs.cartpole_drawing import DrawCartPole
from trl_cartpole.envs.pixels import CropFrame, PoolImage, RandomShift
from trl_cartpole.errors import ConfigError
from trl_cartpole.policy.load import evaluate_checkpoint, load_trained_policy
from trl_cartpole.run import resources
from trl_cartpole.run.build import build_components
from trl_cartpole.run.eval_protocol import EvalProtocol
from trl_cartpole.run.from_config import build_actor, build_env, build_replay_buffer, run_title
from trl_cartpole.run.resources import run_memory_need
from trl_cartpole.run.training import train

# A pixel run small enough for the default tier: 2 envs (one painted by Gymnasium's calls),
# 200 frames, evaluations of 2 episodes.
TINY_PIXEL_RUN = [
    "env=cartpole_pixels",
    "env.num_envs=2",
    "env.pixels_rendered_share=0.5",
    "collector.total_frames=200",
    "collector.init_random_frames=64",
    "collector.frames_per_batch=8",
    "buffer.max_size=500",
    "buffer.batch_size=16",
    "eval.interval_frames=100",
    "eval.episodes=2",
    "eval.final_episodes=2",
    "eval.candidate_episodes=2",  # the preset's 3 candidates: here the 2 evaluations' policies
    "eval.max_steps=50",
    "checkpoint.interval_frames=100",
    "logger.progress_bar=false",
    "logger.plots=false",
]


def test_crop_keeps_the_band_and_pool_averages_blocks_to_uint8():
    frame = torch.arange(6 * 8 * 3, dtype=torch.uint8).reshape(6, 8, 3)  # [H, W, C]
    band = CropFrame([1, 5, 2, None])._apply_transform(frame)
    assert band.shape == (4, 6, 3) and torch.equal(band, frame[1:5, 2:])
    image = torch.tensor([[[0.0, 2.0, 10.0, 10.0], [4.0, 6.0, 10.0, 11.0]]])  # [1, 2, 4]
    pooled = PoolImage(2)._apply_transform(image)
    # block means (0 + 2 + 4 + 6) / 4 = 3 and (10 + 10 + 10 + 11) / 4 = 10.25 -> 10
    assert pooled.dtype == torch.uint8 and pooled.tolist() == [[[3, 10]]]


@pytest.mark.parametrize(
    ("renderer", "share"), [("drawn", 1.0), ("drawn", 0.5), ("drawn", 0), ("gymnasium", 0)]
)
def test_the_preset_shows_the_network_pixels_only(compose, renderer, share):
    overrides = [f"env.pixels_renderer={renderer}", f"env.pixels_rendered_share={share}"]
    cfg = validate(to_config(compose("env=cartpole_pixels", "env.num_envs=2", *overrides)))
    env = build_env(cfg, seed=0)
    spec = env.observation_spec
    assert "observation" not in spec.keys()  # noqa: SIM118 (a spec): the state is not there
    pixels = spec["pixels"]
    assert pixels.dtype == torch.uint8 and tuple(pixels.shape) == (2, 3, 20, 60)  # [E, 3, h, w]
    actor = build_actor(cfg, env)
    assert actor.in_keys == ["pixels"]
    frames = env.reset()
    assert frames["pixels"].float().std() > 0  # a rendered scene, not a blank
    # The actor acts on the frames alone: a tensordict holding nothing else.
    only_pixels = TensorDict({"pixels": frames["pixels"]}, batch_size=[2])
    assert actor(only_pixels)["action"].shape == (2, 2)
    # The buffer keeps uint8: a transition is at least the frames now and next, a byte each.
    need = run_memory_need(cfg, env)
    assert need.transition_bytes >= 2 * 3 * 20 * 60  # frames now and next, 3 patches each
    assert need.transition_bytes < 2 * 3 * 20 * 60 + 200  # not float32 (4 bytes a pixel)
    env.close()


@pytest.mark.parametrize("algo", ["dqn", "double", "dueling", "noisy", "c51", "rainbow"])
def test_the_cnn_torso_composes_with_every_head_and_variant(compose, algo):
    cfg = validate(to_config(compose(f"algo={algo}", "env=cartpole_pixels", "env.num_envs=2")))
    assert cfg.network.torso == "cnn"
    env = build_env(cfg, seed=0)
    actor = build_actor(cfg, env)
    values = actor(env.reset())["action_value"]
    assert values.shape == ((2, cfg.network.atoms, 2) if cfg.network.distributional else (2, 2))
    env.close()


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["env.from_pixels=true"], "pixels need the cnn torso"),
        (["network.torso=cnn"], "the cnn torso needs pixels"),
        (["env=cartpole_pixels", "network.cnn_kwargs.kernel_sizes=[5,5]"], "one entry per layer"),
        (["env=cartpole_pixels", "env.normalize_observations=true"], "pixels have none"),
    ],
)
def test_impossible_pixel_configs_are_refused(compose, overrides, message):
    with pytest.raises(ConfigError, match=message):
        validate(to_config(compose(*overrides)))


@pytest.mark.slow  # a pixel run resumed
def test_a_short_pixel_run_trains_evaluates_and_resumes(tmp_path):
    run_dir = tmp_path / "run"
    proc = run_script_in_process("train.py", *TINY_PIXEL_RUN, f"run_dir={run_dir}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["frames"] == 200 and summary["updates"] > 0
    assert len(summary["final_eval_returns"]) == 2
    # A resume continues the episodes (the stacked frames are stored with the envs' state)
    # and adds the frames.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        more = run_script_in_process("train.py", f"resume={run_dir}", "collector.total_frames=296")
    assert not [w for w in caught if "new episodes" in str(w.message)]
    assert more.returncode == 0, more.stderr[-2000:]
    assert json.loads((run_dir / "summary.json").read_text())["frames"] == 296
    # More episodes than pixel envs built at once are played in turns (each env a renderer).
    trained = load_trained_policy(run_dir)
    trained.env.close()
    sizes = []

    class CountingProtocol(EvalProtocol):
        def make_envs(self, seed, count):
            sizes.append(count)
            return super().make_envs(seed, count)

    protocol = CountingProtocol(
        **vars(EvalProtocol.from_config(trained.cfg)) | {"pixel_envs_at_once": 2}
    )
    result = protocol.play(trained.actor, protocol.seed_for("final"), 5)
    assert sizes == [2, 2, 1] and len(result.returns) == len(result.lengths) == 5
    result, _ = evaluate_checkpoint(run_dir, episodes=5)  # the script's path: 20 at a time
    assert len(result.returns) == 5
    assert all(1 <= length <= 50 for length in result.lengths)  # eval.max_steps=50


def _drawn_envs(env) -> tuple[int, int]:
    """(envs, envs painted by Gymnasium's calls) of a drawn pixel env."""
    (draw,) = [t for t in env.transform if isinstance(t, DrawCartPole)]
    return env.batch_size.numel(), draw.rendered


def test_a_drawn_run_learns_on_its_share_and_is_evaluated_on_gymnasiums_frames(tmp_path, compose):
    evaluated = []  # the envs the end of the run evaluates on: the candidates, then the final

    class RecordingProtocol(EvalProtocol):
        def make_envs(self, seed, count):
            env = super().make_envs(seed, count)
            evaluated.append(_drawn_envs(env))
            return env

    built = {}

    def build_and_look(cfg, resume=None):
        components = build_components(cfg, resume)
        built["training"], built["periodic"] = map(
            _drawn_envs, (components.env, components.eval_env)
        )
        components.protocol = RecordingProtocol(**vars(components.protocol))
        return components

    overrides = ["env.num_envs=4", "env.pixels_rendered_share=0.5", "eval.episodes=3"]
    train(compose(*TINY_PIXEL_RUN, *overrides, f"run_dir={tmp_path / 'run'}"), build=build_and_look)
    assert built["training"] == (4, 2)  # 2 of its 4 envs painted by Gymnasium's calls
    # the periodic evaluations and the candidates' new episodes (which choose the policy to
    # keep) and the final evaluation: every frame
    assert built["periodic"] == (3, 3) and evaluated == [(2, 2), (2, 2), (2, 2)]


def test_periodic_evaluations_hold_no_more_pixel_envs_than_the_final_one(compose):
    cfg = validate(to_config(compose(*TINY_PIXEL_RUN, "eval.episodes=5", "eval.max_steps=5")))
    actor = build_actor(cfg, build_env(cfg, seed=0))
    protocol = replace(EvalProtocol.from_config(cfg), pixel_envs_at_once=2)
    periodic = protocol.periodic()
    try:
        assert _drawn_envs(periodic.env) == (2, 2)  # one env of 2, kept for the run
        first, second = periodic.play(actor), periodic.play(actor)
    finally:
        periodic.close()
    assert len(first.returns) == len(first.initial_values) == 5  # turns of 2, 2 and 1
    # each turn and each evaluation continues the envs' random streams: new first states
    starts = first.initial_values + second.initial_values
    assert len(set(starts)) == len(starts)


@pytest.mark.slow  # a pixel run, then its video and its exported policy
def test_render_and_export_take_the_agents_frames(tmp_path):
    onnxruntime = pytest.importorskip("onnxruntime")
    from PIL import Image

    from trl_cartpole.policy.export import greedy_q_network
    from trl_cartpole.policy.load import load_trained_policy

    run_dir = tmp_path / "run"
    proc = run_script_in_process("train.py", *TINY_PIXEL_RUN, f"run_dir={run_dir}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    gif = tmp_path / "agent.gif"
    shown = run_script_in_process(
        "render.py", f"checkpoint={run_dir}", f"output={gif}", "episodes=1", "scale=0.5"
    )
    assert shown.returncode == 0, shown.stderr[-2000:]
    from trl_cartpole.policy.video import VIEW_CAPTION_HEIGHT

    # the scene (300 x 200 at scale 0.5), a caption, then what the agent saw (20 rows, x5)
    assert Image.open(gif).size == (300, 200 + VIEW_CAPTION_HEIGHT + 5 * 20)
    onnx_file = tmp_path / "policy.onnx"
    exported = run_script_in_process("export.py", f"checkpoint={run_dir}", f"output={onnx_file}")
    assert exported.returncode == 0, exported.stderr[-2000:]
    assert "pixels [batch, 3, 20, 60] uint8" in exported.stdout
    trained = load_trained_policy(run_dir, num_envs=3)
    frames = trained.env.reset()["pixels"]  # [3, 3, 20, 60] uint8
    session = onnxruntime.InferenceSession(str(onnx_file))
    (values,) = session.run(None, {"pixels": frames.numpy()})
    expected = trained.actor(TensorDict({"pixels": frames}, batch_size=[3]))["action_value"]
    assert torch.allclose(torch.from_numpy(values), expected, atol=1e-5)
    assert greedy_q_network(run_dir).input_shape == (3, 20, 60)
    trained.env.close()


def test_a_budget_that_ends_before_the_first_update_is_warned_in_one_line(compose):
    cfg = validate(to_config(compose("env=cartpole_pixels", "collector.total_frames=3000")))
    with pytest.warns(
        UserWarning,
        match=r"total_frames=3000 ends before the first update at "
        r"frame 5000",
    ) as caught:
        resources.warn_if_no_update(cfg)
    assert "\n" not in str(caught[0].message)
    long_enough = validate(to_config(compose("env=cartpole_pixels")))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        resources.warn_if_no_update(long_enough)  # the preset's whole budget: no warning


def test_the_final_evaluation_of_pixels_says_how_many_episodes_it_played(compose):
    cfg = validate(to_config(compose(*TINY_PIXEL_RUN, "eval.max_steps=5")))
    actor = build_actor(cfg, build_env(cfg, seed=0))
    protocol = replace(
        EvalProtocol.from_config(cfg), pixel_envs_at_once=2
    )  # turns of 2: 2, 4, 5 episodes
    played = []
    result = protocol.play(actor, seed=0, episodes=5, on_turn=played.append)
    assert played == [2, 4, 5] and len(result.returns) == 5


def test_a_pixel_runs_directory_and_plots_say_it_learns_from_pixels(compose):
    pixels = to_config(compose("env=cartpole_pixels", "seed=4"))
    state = to_config(compose("seed=4"))
    assert pixels.run_dir.startswith("runs/CartPole-v1-pixels-dqn-seed4-")
    assert state.run_dir.startswith("runs/CartPole-v1-dqn-seed4-")
    assert run_title(pixels) == "CartPole-v1 from pixels dqn seed 4"
    assert run_title(state) == "CartPole-v1 dqn seed 4"


def _shifted(image: torch.Tensor, dy: int, dx: int, pad: int) -> torch.Tensor:
    """``image`` [C, H, W] moved by (dy, dx) with its edge repeated: what RandomShift crops."""
    padded = torch.nn.functional.pad(image[None].float(), (pad,) * 4, mode="replicate")[0]
    height, width = image.shape[-2:]
    return padded[:, pad + dy : pad + dy + height, pad + dx : pad + dx + width].to(image.dtype)


def test_random_shift_moves_each_frame_by_at_most_pad_pixels_independently():
    torch.manual_seed(0)
    frames = torch.randint(0, 256, (64, 2, 20, 60), dtype=torch.uint8)  # [B, frames, h, w]
    batch = TensorDict({"pixels": frames, ("next", "pixels"): frames.clone()}, [64])
    out = RandomShift(pad=2)(batch.clone())
    moves = {"pixels": [], ("next", "pixels"): []}
    for key, found in moves.items():
        assert out[key].shape == frames.shape and out[key].dtype == torch.uint8
        for image, original in zip(out[key], frames, strict=True):
            matches = [
                (dy, dx)
                for dy in range(-2, 3)
                for dx in range(-2, 3)
                if torch.equal(image, _shifted(original, dy, dx, pad=2))
            ]
            assert matches, "not a shift of the original by at most 2 pixels"
            found.append(matches[0])
    assert len(set(moves["pixels"])) > 10  # all 25 moves are drawn, ...
    assert moves["pixels"] != moves["next", "pixels"]  # ... independently for now and next


@pytest.mark.parametrize(("shape", "pad"), [((6, 4, 84, 84), 4), ((3, 5, 2, 20, 60), 1)])
def test_random_shift_is_the_edge_repeating_pad_cropped_at_the_drawn_offsets(shape, pad):
    frames = torch.randint(0, 256, shape, dtype=torch.uint8)  # [*B, C, H, W]
    batch = TensorDict({"pixels": frames, ("next", "pixels"): frames.clone()}, shape[:-3])
    torch.manual_seed(3)
    out = RandomShift(pad=pad)(batch.clone())
    torch.manual_seed(3)  # the same draws, in the same order: now, then next
    for key in ("pixels", ("next", "pixels")):
        images = frames.reshape(-1, *shape[-3:])
        tops, lefts = torch.randint(0, 2 * pad + 1, (2, len(images))).tolist()
        expected = torch.stack(
            [
                _shifted(image, top - pad, left - pad, pad)
                for image, top, left in zip(images, tops, lefts, strict=True)
            ]
        )
        assert torch.equal(out[key], expected.reshape(shape)), key


def test_a_shifting_buffer_stores_the_frames_as_collected(compose):
    cfg = validate(to_config(compose(*TINY_PIXEL_RUN, "buffer.pixels_shift=1", "buffer.n_steps=1")))
    buffer = build_replay_buffer(cfg)
    frames = torch.randint(0, 256, (40, 2, 20, 60), dtype=torch.uint8)
    data = TensorDict(
        {
            "pixels": frames,
            "action": torch.zeros(40, 2),
            ("next", "pixels"): frames,
            ("next", "reward"): torch.ones(40, 1),
            ("next", "done"): torch.zeros(40, 1, dtype=torch.bool),
            ("next", "terminated"): torch.zeros(40, 1, dtype=torch.bool),
            ("next", "truncated"): torch.zeros(40, 1, dtype=torch.bool),
        },
        [40],
    )
    buffer.extend(data)
    sample = buffer.sample(16)
    assert sample["pixels"].shape == (16, 2, 20, 60)
    stored = buffer.storage.get(torch.arange(40))  # the storage itself: no transform
    assert torch.equal(stored["pixels"], frames)
    index = sample["index"]
    assert not torch.equal(sample["pixels"], stored["pixels"][index])  # the sample is shifted


def test_a_shift_without_pixels_is_refused(compose):
    with pytest.raises(ConfigError, match=r"buffer\.pixels_shift=1 shifts frames"):
        validate(to_config(compose("buffer.pixels_shift=1")))
