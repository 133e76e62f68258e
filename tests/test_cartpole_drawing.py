"""CartPole drawn from its states (env.pixels_renderer=drawn) against Gymnasium's render().

The drawn frame must be the frame the pixel preset makes from ``render()``: crop, TorchRL's
``GrayScale``, a ``pool x pool`` mean rounded to uint8. It differs only on the antialiased
edges pygame draws: over 150 random states the mean absolute error stays under 0.13 gray
levels (0.077-0.086 measured at 20x60, 40x120 and 60x130) and no pooled pixel is off by more
than 48 (17, 38 and 45 measured, single pixels on an edge).
"""

from __future__ import annotations

import copy
import os
import pickle
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
import torch
from torchrl.envs.transforms.functional import rgb_to_grayscale

from trl_cartpole.config.schema import to_config
from trl_cartpole.config.validation import validate
from trl_cartpole.envs.cartpole_drawing import DrawCartPole, draw_cartpole, render_cartpole
from trl_cartpole.errors import ConfigError
from trl_cartpole.run.envs import make_pixel_env, rendered_envs
from trl_cartpole.run.eval_protocol import EvalProtocol
from trl_cartpole.run.from_config import build_actor

CROP = (120, 320, None, None)  # the preset's band of rows


def _rendered(states: np.ndarray, crop, pool: int, **attributes) -> torch.Tensor:
    """render() -> crop -> gray -> pool -> uint8, ``[N, 1, h, w]``: the pixel preset's path
    (``attributes`` set on the env: its pole ``length``, its ``x_threshold``)."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    env = gym.make("CartPole-v1", render_mode="rgb_array").unwrapped
    env.reset(seed=0)
    for name, value in attributes.items():
        setattr(env, name, value)
    frames = []
    for state in states:
        env.state = state.copy()
        frames.append(env.render())
    env.close()
    top, bottom, left, right = crop
    rgb = torch.from_numpy(np.stack(frames))[:, top:bottom, left:right]  # [N, h0, w0, 3]
    gray = rgb_to_grayscale(rgb.permute(0, 3, 1, 2).float())  # [N, 1, h0, w0], as ToTensorImage
    pooled = torch.nn.functional.avg_pool2d(gray, pool)
    return pooled.round().clamp(0, 255).to(torch.uint8)


def _random_states(count: int, seed: int, angle: float = 0.25) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack(
        [
            rng.uniform(-2.4, 2.4, count),  # the cart anywhere on the track
            rng.normal(0, 1, count),
            rng.uniform(-angle, angle, count),  # beyond the 0.21 rad an episode ends at
            rng.normal(0, 1, count),
        ],
        axis=1,
    )


@pytest.mark.parametrize(("crop", "pool"), [(CROP, 10), (CROP, 5), ((100, 340, 40, 560), 4)])
def test_drawn_frames_match_gymnasiums_render_on_random_states(crop, pool):
    states = _random_states(150, seed=pool)
    expected = _rendered(states, crop, pool)
    drawn = draw_cartpole(torch.tensor(states), crop, pool)
    assert drawn.dtype == torch.uint8 and drawn.shape == expected.shape
    error = (drawn.int() - expected.int()).abs().float()
    assert error.mean() < 0.13, error.mean()
    assert error.max() <= 48, error.max()
    assert error.mean((1, 2, 3)).max() < 0.3  # no frame is off as a whole
    assert (expected < 200).any((1, 2, 3)).all()  # every frame shows the cart


def test_a_longer_pole_on_a_wider_track_is_drawn_as_gymnasium_draws_it():
    states = _random_states(40, seed=1, angle=0.6)
    states[:, 0] *= 3.0 / 2.4
    expected = _rendered(states, CROP, 10, length=0.8, x_threshold=3.0)
    drawn = draw_cartpole(torch.tensor(states), CROP, 10, length=0.8, x_threshold=3.0)
    assert (drawn.int() - expected.int()).abs().float().mean() < 0.13


def test_the_transform_draws_any_batch_shape_and_declares_its_spec():
    transform = DrawCartPole(CROP, 10)
    states = torch.tensor(_random_states(6, seed=2), dtype=torch.float32).reshape(2, 3, 4)
    pixels = transform._apply_transform(states)
    assert pixels.shape == (2, 3, 1, 20, 60)
    torch.testing.assert_close(pixels[1, 2], draw_cartpole(states[1, 2], CROP, 10))


def test_the_drawn_env_plays_the_rendered_envs_episode_frame_for_frame(compose):
    rendered_cfg = validate(
        to_config(
            compose(
                "env=cartpole_pixels",
                "env.pixels_renderer=gymnasium",
                "env.pixels_rendered_share=0",
            )
        )
    )
    drawn_cfg = validate(to_config(compose("env=cartpole_pixels", "env.pixels_rendered_share=0")))
    rendered = make_pixel_env(rendered_cfg.env, seed=7, num_envs=1)
    drawn = make_pixel_env(drawn_cfg.env, seed=7, num_envs=1)
    exact = make_pixel_env(replace(drawn_cfg.env, pixels_rendered_share=1.0), seed=7, num_envs=1)
    assert rendered.observation_spec == drawn.observation_spec  # pixels [3, 20, 60] uint8 only
    torch.manual_seed(0)
    expected = rendered.rollout(60, break_when_any_done=False)
    for env in (drawn, exact):
        torch.manual_seed(0)
        got = env.rollout(60, break_when_any_done=False)
        assert torch.equal(got["action"], expected["action"])
        assert torch.equal(got["next", "done"], expected["next", "done"])
        assert torch.equal(got["next", "reward"], expected["next", "reward"])
        error = (got["next", "pixels"].int() - expected["next", "pixels"].int()).abs().float()
        assert error.mean() < 0.13 and error.max() <= 48
    assert error.max() == 0  # every frame rendered: Gymnasium's own, pixel for pixel


@pytest.mark.parametrize(
    ("crop", "pool", "attributes"),
    [
        ((120, 325, None, None), 10, {}),  # rows beyond the last whole block dropped, as pooled
        ((100, 340, 40, 560), 4, {}),
        (CROP, 1, {"length": 0.8, "x_threshold": 3.0}),
    ],
)
def test_the_canvas_paints_gymnasiums_own_frames_pixel_for_pixel(crop, pool, attributes):
    states = _random_states(60, seed=11, angle=0.6)
    states[:, 0] *= attributes.get("x_threshold", 2.4) / 2.4
    expected = _rendered(states, crop, pool, **attributes)
    got = render_cartpole(torch.tensor(states), crop, pool, **attributes)
    assert got.shape == expected.shape and torch.equal(got, expected)


def test_a_share_paints_its_envs_rounded_up():
    assert [rendered_envs(0.25, n) for n in (1, 2, 4, 5, 8)] == [1, 1, 1, 2, 2]
    assert rendered_envs(0.3, 10) == 3 and rendered_envs(0.0, 8) == 0  # no float overshoot
    assert rendered_envs(1.0, 20) == 20


def test_a_drawn_transform_that_has_painted_copies_and_pickles_without_its_surface():
    draw = DrawCartPole(CROP, 10, rendered=1)
    states = torch.tensor(_random_states(2, seed=2)).float()
    frames = draw._apply_transform(states)
    assert draw._canvas is not None  # a pygame surface, which cannot be pickled
    for twin in (copy.deepcopy(draw), pickle.loads(pickle.dumps(draw))):
        assert twin._canvas is None and twin.rendered == 1
        assert torch.equal(twin._apply_transform(states), frames)


def test_the_rendered_share_of_a_drawn_batch_is_gymnasiums_own_frames():
    states = torch.tensor(_random_states(12, seed=5)).float().reshape(3, 4, 4)  # batch [3, 4]
    expected = _rendered(states.reshape(12, 4).double().numpy(), CROP, 10)  # [12, 1, 20, 60]
    drawn = draw_cartpole(states, CROP, 10).reshape(12, 1, 20, 60)
    assert not torch.equal(drawn, expected)  # the drawing alone differs on a few edge pixels
    frames = DrawCartPole(CROP, 10, rendered=5)._apply_transform(states)
    assert frames.shape == (3, 4, 1, 20, 60)
    frames = frames.reshape(12, 1, 20, 60)  # the batch's flattened order
    assert torch.equal(frames[:5], expected[:5])  # the first 5 envs rendered by Gymnasium
    assert torch.equal(frames[5:], drawn[5:])  # the rest drawn
    assert torch.equal(render_cartpole(states, CROP, 10).reshape(12, 1, 20, 60), expected)


def test_a_batch_of_drawn_envs_is_one_vector_env_and_evaluation_uses_gymnasiums_frames(compose):
    cfg = validate(to_config(compose("env=cartpole_pixels", "env.pixels_renderer=drawn")))
    env = make_pixel_env(cfg.env, seed=0, num_envs=8)
    assert env.batch_size == (8,)
    assert "observation" not in env.observation_spec.keys()  # noqa: SIM118 (a spec)
    frames = env.reset()["pixels"]  # [8, 3, 20, 60]
    assert frames.shape == (8, 3, 20, 60) and frames.float().std() > 0
    built = []  # (envs, envs painted by Gymnasium's calls) of each evaluation env

    class RecordingProtocol(EvalProtocol):
        def make_envs(self, seed, count):
            evaluated = super().make_envs(seed, count)
            (draw,) = [t for t in evaluated.transform if isinstance(t, DrawCartPole)]
            built.append((evaluated.batch_size.numel(), draw.rendered))
            return evaluated

    protocol = RecordingProtocol(**vars(EvalProtocol.from_config(cfg)))
    result = protocol.play(build_actor(cfg, env), seed=3, episodes=2)
    assert built == [(2, 2)] and len(result.returns) == 2  # one drawn env, every frame rendered


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["env=acrobot", "env.pixels_renderer=drawn"], "draws CartPole from pixels only"),
        (["env.pixels_renderer=drawn"], "draws CartPole from pixels only"),
        (["env=cartpole_pixels", "env.pixels_renderer=pygame"], "env.pixels_renderer"),
        (["env=cartpole_pixels", "env.pixels_rendered_share=1.5"], "between 0 and 1"),
        (["env.pixels_rendered_share=0.5"], "or use env=cartpole_pixels"),
        (
            ["env=cartpole_pixels", "env.pixels_renderer=gymnasium"],
            "mixes Gymnasium's frames into drawn ones",
        ),
    ],
)
def test_a_renderer_that_cannot_draw_the_env_is_refused_in_one_line(compose, overrides, message):
    with pytest.raises(ConfigError, match=message) as raised:
        validate(to_config(compose(*overrides)))
    assert "\n" not in str(raised.value)


def test_a_crop_is_read_as_python_slices_like_the_rendered_path():
    states = torch.tensor(_random_states(4, seed=3))
    negative = draw_cartpole(states, (120, -80, None, None), 10)  # rows 120-320, as CropFrame
    torch.testing.assert_close(negative, draw_cartpole(states, CROP, 10))
    beyond = draw_cartpole(states, (120, 900, None, None), 10)  # to the frame's edge
    assert beyond.shape == (4, 1, 28, 60)
    with pytest.raises(ValueError, match="keeps less than one 10x10 block"):
        draw_cartpole(states, (120, 125, None, None), 10)


def test_a_drawn_crop_smaller_than_a_block_is_refused_in_one_line(compose):
    with pytest.raises(ConfigError, match=r"keeps less than one 10x10 block"):
        validate(to_config(compose("env=cartpole_pixels", "env.pixels_crop=[120,125,null,null]")))
