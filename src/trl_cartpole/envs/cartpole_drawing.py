"""CartPole's picture drawn for a batch of states at once, straight at the pooled resolution.

Gymnasium's ``CartPoleEnv.render()`` draws one 600x400 frame with pygame: a white screen, the
cart (a black 50x30 rectangle whose top is 100 px above the bottom edge), the pole (a 10 px
wide rectangle of colour (202, 152, 101), ``2 * length * 125`` px long, turned by the angle
about the axle 7.5 px below the cart's top), the axle (a circle of radius 5, (129, 132, 203))
and the track (a black line across the screen at the cart's top), 125 px a metre. The pixel
preset crops that frame, turns it gray and averages ``pool x pool`` blocks
(:mod:`trl_cartpole.envs.pixels`). :func:`draw_cartpole` computes the same pooled gray image
from the states directly: each full-resolution row crossed by a shape is an interval per
shape (the pole's from its four edge inequalities), the painter's order is kept by
inclusion-exclusion of those intervals, and each pooled pixel is the exact mean of its block
of rows and columns. Pygame's antialiased outlines are modelled as half a pixel on each side
of a filled row and its float vertices as truncated, so edges differ by a few gray levels
(measured against ``render()`` in ``tests/test_cartpole_drawing.py``; docs/environments.md,
"The picture drawn from the states"). The crop is read as Python slices, as ``CropFrame``
reads it. :func:`render_cartpole` gives the exact frame: Gymnasium's own drawing calls
(:class:`CartPoleCanvas`, about 0.4 ms a frame).
:class:`DrawCartPole` is the TorchRL transform that draws a state env's observation; its
``rendered`` first envs are rendered by Gymnasium instead, so a network trained on it also
sees the frames it is evaluated on.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import torch
from torchrl.data.tensor_specs import Bounded, TensorSpec
from torchrl.envs.transforms import Transform
from torchrl.envs.transforms.functional import rgb_to_grayscale

from trl_cartpole.envs.ids import CARTPOLE_FRAME, cartpole_crop_bounds

__all__ = [
    "SCREEN_HEIGHT",
    "SCREEN_WIDTH",
    "CartPoleCanvas",
    "DrawCartPole",
    "draw_cartpole",
    "render_cartpole",
]

SCREEN_HEIGHT, SCREEN_WIDTH = CARTPOLE_FRAME  # CartPoleEnv.render()'s frame
CART_WIDTH, CART_HEIGHT, POLE_WIDTH = 50.0, 30.0, 10.0  # px
CART_TOP = 100  # px above the bottom edge: also the track's row
AXLE_HEIGHT = CART_TOP + CART_HEIGHT / 4  # the pole turns about (cart x, 107.5)
AXLE_RADIUS = 5  # int(POLE_WIDTH / 2), pygame draws it at whole pixels
WHITE, CART_RGB, POLE_RGB, AXLE_RGB = (255, 255, 255), (0, 0, 0), (202, 152, 101), (129, 132, 203)
# pygame truncates each float vertex to a whole pixel: the cart and pole sit on average half a
# pixel left of and below where the state puts them (measured: the pooled error 0.17 -> 0.08)
TRUNCATION = 0.5


def _gray(rgb: tuple[int, int, int]) -> float:
    """The gray level TorchRL's ``GrayScale`` gives this colour."""
    pixel = torch.tensor(rgb, dtype=torch.float64).reshape(3, 1, 1)
    return float(rgb_to_grayscale(pixel).item())


def _overlap(low: torch.Tensor, high: torch.Tensor, left: torch.Tensor, right: torch.Tensor):
    """Length of ``[low, high] & [left, right]`` (0 when apart), broadcast."""
    return (torch.minimum(high, right) - torch.maximum(low, left)).clamp_min(0.0)


def _solve(coef: torch.Tensor, offset: torch.Tensor, low: float, high: float):
    """The interval of ``d`` with ``low <= coef * d + offset <= high`` (coef may be 0)."""
    inf = torch.full_like(offset, torch.inf)
    safe = torch.where(coef == 0, torch.ones_like(coef), coef)
    a, b = (low - offset) / safe, (high - offset) / safe
    lo, hi = torch.minimum(a, b), torch.maximum(a, b)
    inside = (offset >= low) & (offset <= high)
    lo = torch.where(coef == 0, torch.where(inside, -inf, inf), lo)
    hi = torch.where(coef == 0, torch.where(inside, inf, -inf), hi)
    return lo, hi


def draw_cartpole(
    state: torch.Tensor,
    crop: Sequence[int | None] = (None, None, None, None),
    pool: int = 1,
    length: float = 0.5,
    x_threshold: float = 2.4,
) -> torch.Tensor:
    """``render()`` -> crop -> gray -> ``pool x pool`` mean, for a batch of CartPole states.

    :param state: ``[*B, 4]`` CartPole states (x, x_dot, theta, theta_dot).
    :param crop: rows ``[top, bottom)`` and columns ``[left, right)`` of the 400x600 frame
        (``None``: up to the edge), as :class:`~trl_cartpole.envs.pixels.CropFrame` takes it.
    :param pool: the block size the cropped frame is averaged over.
    :param length: the env's half pole length (``CartPoleEnv.length``).
    :param x_threshold: the env's ``x_threshold`` (the screen spans twice it).
    :returns: ``[*B, 1, h // pool, w // pool]`` uint8 gray pixels.
    """
    top, bottom, left, right = cartpole_crop_bounds(crop)
    if min(bottom - top, right - left) < pool:
        raise ValueError(f"crop {list(crop)} keeps less than one {pool}x{pool} block")
    height, width = (bottom - top) // pool, (right - left) // pool
    lead = state.shape[:-1]
    dtype = torch.float32
    state = state.reshape(-1, 4).to(dtype)  # [N, 4]
    scale = SCREEN_WIDTH / (2 * x_threshold)  # px a metre
    pole_length = scale * 2 * length

    # The full-resolution rows of the crop, bottom-up as pygame draws them (image row r is
    # pygame's row 399 - r); pixel k spans [k - 1/2, k + 1/2].
    image_rows = torch.arange(top, top + height * pool, dtype=dtype, device=state.device)  # [R]
    y = (SCREEN_HEIGHT - 1 - image_rows)[None, :]  # [1, R]
    cart_x = (state[:, 0] * scale + SCREEN_WIDTH / 2)[:, None]  # [N, 1]
    cos, sin = state[:, 2].cos()[:, None], state[:, 2].sin()[:, None]  # [N, 1]

    cart, pole, axle = _shape_spans(cart_x, cos, sin, y, pole_length)  # each ([N, R], [N, R])

    # Only the pooled columns the shapes reach are computed: a window of K columns per env.
    x_min = torch.stack([cart[0], pole[0], axle[0]], 1).flatten(1).amin(1)  # [N]; inf: none
    x_max = torch.stack([cart[1], pole[1], axle[1]], 1).flatten(1).amax(1)  # [N]
    origin = left - 0.5  # the left edge of the crop's first pixel
    first = ((x_min - origin) / pool).floor().nan_to_num(0, 0, 0).clamp(0, width - 1)
    last = ((x_max - origin) / pool).floor().nan_to_num(0, 0, 0).clamp(0, width - 1)
    window = int((last - first).clamp_min(0).max().item()) + 1 if len(first) else 1
    first = first.clamp(max=width - window).long()  # [N]
    columns = first[:, None] + torch.arange(window, device=state.device)  # [N, K]
    col_lo = (origin + pool * columns.to(dtype))[:, None, :]  # [N, 1, K]
    col_hi = col_lo + pool

    def covered(*intervals):  # [N, R, K]: the length of the shapes' common part per column
        lo = torch.stack([i[0] for i in intervals]).amax(0)[..., None]
        hi = torch.stack([i[1] for i in intervals]).amin(0)[..., None]
        return _overlap(lo, hi, col_lo, col_hi)

    visible_axle = covered(axle)
    visible_pole = covered(pole) - covered(pole, axle)
    visible_cart = covered(cart) - covered(cart, pole) - covered(cart, axle)
    visible_cart = visible_cart + covered(cart, pole, axle)
    white = _gray(WHITE)
    darkening = (
        (white - _gray(CART_RGB)) * visible_cart
        + (white - _gray(POLE_RGB)) * visible_pole
        + (white - _gray(AXLE_RGB)) * visible_axle
    )  # [N, R, K]: how much darker than white each row's span of a pooled pixel is, summed
    track = (y == CART_TOP)[..., None]  # [1, R, 1]: the track is drawn last, black, full width
    darkening = darkening.masked_fill(track, 0.0)
    blocks = darkening.reshape(-1, height, pool, window).sum(2)  # [N, h, K]
    dark = torch.zeros(len(state), height, width, dtype=dtype, device=state.device)
    dark.scatter_add_(2, columns[:, None, :].expand(-1, height, -1), blocks)  # [N, h, w]
    track_rows = track[0, :, 0].to(dtype).reshape(height, pool).sum(1)  # [h]
    dark += (white - _gray(CART_RGB)) * pool * track_rows[None, :, None]
    pixels = (white - dark / pool**2).round().clamp(0, 255).to(torch.uint8)
    return pixels.reshape(*lead, 1, height, width)


def _shape_spans(
    cart_x: torch.Tensor,
    cos: torch.Tensor,
    sin: torch.Tensor,
    y: torch.Tensor,
    pole_length: float,
) -> tuple[tuple[torch.Tensor, torch.Tensor], ...]:
    """The cart's, the pole's and the axle's span of x on each row, ``([N, R], [N, R])`` each
    (from, to; empty rows from +inf to -inf), widened by half a pixel each side.

    ``cart_x``, ``cos``, ``sin``: ``[N, 1]``; ``y``: ``[1, R]``, pygame's rows bottom-up.
    """
    ones = torch.ones_like(cart_x * y)  # [N, R]
    in_cart = (y >= CART_TOP - CART_HEIGHT / 2) & (y <= CART_TOP + CART_HEIGHT / 2)
    drawn_x = cart_x - TRUNCATION
    cart = (drawn_x - CART_WIDTH / 2) * ones, (drawn_x + CART_WIDTH / 2) * ones
    cart = torch.where(in_cart, cart[0], torch.inf), torch.where(in_cart, cart[1], -torch.inf)
    # the pole: u = cos * dx - sin * dy in [-w/2, w/2], v = sin * dx + cos * dy in
    # [-w/2, L - w/2], with (dx, dy) from the axle (pygame's rotate_rad(-theta)).
    dy = y + TRUNCATION - AXLE_HEIGHT  # [1, R]
    u_lo, u_hi = _solve(cos * ones, -sin * dy, -POLE_WIDTH / 2, POLE_WIDTH / 2)
    v_lo, v_hi = _solve(sin * ones, cos * dy, -POLE_WIDTH / 2, pole_length - POLE_WIDTH / 2)
    pole = drawn_x + torch.maximum(u_lo, v_lo), drawn_x + torch.minimum(u_hi, v_hi)
    axle_x = cart_x.floor()  # pygame's int() of a positive coordinate
    axle_dy = y - int(AXLE_HEIGHT)
    half = (AXLE_RADIUS**2 - axle_dy**2).clamp_min(0).sqrt()  # [1, R]
    in_axle = axle_dy.abs() <= AXLE_RADIUS
    axle = (
        torch.where(in_axle, axle_x - half, torch.inf),
        torch.where(in_axle, axle_x + half, -torch.inf),
    )
    cart, pole, axle = ((lo - 0.5, hi + 0.5) for lo, hi in (cart, pole, axle))
    return cart, pole, axle


class CartPoleCanvas:
    """Gymnasium's ``CartPoleEnv.render()`` picture, reading only the crop back.

    :meth:`frame` makes the pygame calls ``render()`` makes (Gymnasium 1.x: ``gfxdraw``'s
    antialiased and filled polygons for the cart and pole, the axle's circles, the track's
    line, at the same float coordinates) on one reusable 600x400 surface, then reads the crop's
    rows (flipped, as ``render()`` flips the surface) and turns them gray and pooled as the
    pixel preset's transforms do: ``render()``'s pixels for the state given, pixel for pixel
    (tested; a drawn env passes its float32 observation, where ``render()`` reads the float64
    state, so a vertex at a pixel's edge may, rarely, fall one pixel apart),
    at about 0.4 ms a frame against 1.1 ms for ``render()`` and the transforms (``render()``
    makes a new surface, flips and copies the whole 600x400 frame out).
    """

    def __init__(self) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")  # a quiet console
        import pygame

        self._pygame = pygame
        self.surface = pygame.Surface((SCREEN_WIDTH, SCREEN_HEIGHT))

    def frame(
        self,
        state: Sequence[float],
        crop: tuple[int, int, int, int],
        pool: int,
        length: float,
        x_threshold: float,
    ) -> torch.Tensor:
        """One state's ``[1, h // pool, w // pool]`` uint8 frame (``crop``: top, bottom, left,
        right of the 400x600 frame)."""
        pygame, surface = self._pygame, self.surface
        from pygame import gfxdraw

        scale = SCREEN_WIDTH / (2 * x_threshold)
        pole_length = scale * 2 * length
        surface.fill(WHITE)
        cart_x = state[0] * scale + SCREEN_WIDTH / 2.0  # the cart's middle
        cart_y, axle_offset = CART_TOP, CART_HEIGHT / 4  # its top; the axle below it
        left, right = -CART_WIDTH / 2, CART_WIDTH / 2
        top, bottom = CART_HEIGHT / 2, -CART_HEIGHT / 2
        cart = [
            (x + cart_x, y + cart_y)
            for x, y in ((left, bottom), (left, top), (right, top), (right, bottom))
        ]
        gfxdraw.aapolygon(surface, cart, CART_RGB)
        gfxdraw.filled_polygon(surface, cart, CART_RGB)
        left, right = -POLE_WIDTH / 2, POLE_WIDTH / 2
        top, bottom = pole_length - POLE_WIDTH / 2, -POLE_WIDTH / 2
        pole = []
        for corner in ((left, bottom), (left, top), (right, top), (right, bottom)):
            x, y = pygame.math.Vector2(corner).rotate_rad(-state[2])
            pole.append((x + cart_x, y + cart_y + axle_offset))
        gfxdraw.aapolygon(surface, pole, POLE_RGB)
        gfxdraw.filled_polygon(surface, pole, POLE_RGB)
        axle = (int(cart_x), int(cart_y + axle_offset), AXLE_RADIUS, AXLE_RGB)
        gfxdraw.aacircle(surface, *axle)
        gfxdraw.filled_circle(surface, *axle)
        gfxdraw.hline(surface, 0, SCREEN_WIDTH, cart_y, CART_RGB)

        row_top, row_bottom, col_left, col_right = crop
        row_bottom = row_top + (row_bottom - row_top) // pool * pool  # the rows pooling keeps
        # the surface's rows count up from the bottom: image row r is surface row 399 - r
        cut = (
            slice(col_left, col_right),
            slice(SCREEN_HEIGHT - row_bottom, SCREEN_HEIGHT - row_top),
        )
        channels = [
            pygame.surfarray.pixels_red(surface),  # [600, 400] views of the surface
            pygame.surfarray.pixels_green(surface),
            pygame.surfarray.pixels_blue(surface),
        ]
        rgb = torch.stack([torch.from_numpy(channel[cut]).T for channel in channels]).float()
        del channels  # releases the surface's lock
        gray = rgb_to_grayscale(rgb).flip(-2)  # [1, h0, w0], image rows top-down
        pooled = torch.nn.functional.avg_pool2d(gray, pool)  # [1, h, w]
        return pooled.round().clamp(0, 255).to(torch.uint8)


def render_cartpole(
    state: torch.Tensor,
    crop: Sequence[int | None] = (None, None, None, None),
    pool: int = 1,
    length: float = 0.5,
    x_threshold: float = 2.4,
    canvas: CartPoleCanvas | None = None,
) -> torch.Tensor:
    """What :func:`draw_cartpole` approximates, exactly: Gymnasium's ``render()`` picture of
    each state -> crop -> TorchRL's gray -> ``pool x pool`` mean -> uint8 (the pixel preset's
    path), by :class:`CartPoleCanvas` (``canvas``: one to reuse).
    ``[*B, 4]`` -> ``[*B, 1, h // pool, w // pool]``."""
    canvas = canvas if canvas is not None else CartPoleCanvas()
    bounds = cartpole_crop_bounds(crop)
    lead = state.shape[:-1]
    rows = state.reshape(-1, 4).double().tolist()
    frames = torch.stack([canvas.frame(row, bounds, pool, length, x_threshold) for row in rows])
    return frames.reshape(*lead, *frames.shape[-3:]).to(state.device)


class DrawCartPole(Transform):
    """Draw a CartPole env's ``observation`` (its state) into ``pixels``: ``[*B, 1, h, w]`` uint8,
    the frame ``render()`` -> crop -> gray -> pool gives (:func:`draw_cartpole`).

    Append it to a state env (``make_env("CartPole-v1", num_envs=64)``): one call draws the
    whole batch. Follow it with ``CatFrames`` and ``ExcludeTransform("observation")`` for a
    policy that sees pixels only (:func:`trl_cartpole.envs.pixels.drawn_pixel_transforms`).
    ``rendered``: the first that many envs of the batch (in its flattened order) get
    Gymnasium's exact picture instead (:func:`render_cartpole`, about 0.4 ms a frame).
    """

    def __init__(
        self,
        crop: Sequence[int | None] = (None, None, None, None),
        pool: int = 1,
        length: float = 0.5,
        x_threshold: float = 2.4,
        in_keys: Sequence[str] = ("observation",),
        out_keys: Sequence[str] = ("pixels",),
        rendered: int = 0,
    ) -> None:
        super().__init__(in_keys=list(in_keys), out_keys=list(out_keys))
        self.crop, self.pool = tuple(crop), pool
        self.length, self.x_threshold = length, x_threshold
        self.rendered = rendered
        self._canvas: CartPoleCanvas | None = None  # made on the first rendered frame

    def _apply_transform(self, state: torch.Tensor) -> torch.Tensor:
        shape = (self.crop, self.pool, self.length, self.x_threshold)
        count = state[..., 0].numel()
        if self.rendered and self._canvas is None:
            self._canvas = CartPoleCanvas()
        if self.rendered >= count:  # every frame Gymnasium's picture
            return render_cartpole(state, *shape, self._canvas)  # [*B, 1, h, w]
        pixels = draw_cartpole(state, *shape)  # [*B, 1, h, w]
        if self.rendered:
            flat = pixels.reshape(-1, *pixels.shape[-3:])  # [N, 1, h, w], a view
            rows = state.reshape(-1, 4)[: self.rendered]
            flat[: self.rendered] = render_cartpole(rows, *shape, self._canvas)
        return pixels

    def __getstate__(self) -> dict:  # sent to worker processes without its pygame surface
        state = super().__getstate__()
        state["_canvas"] = None
        return state

    def _reset(self, tensordict, tensordict_reset):
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: TensorSpec) -> TensorSpec:
        for in_key, out_key in zip(self.in_keys, self.out_keys, strict=True):
            state = observation_spec[in_key]
            shape = self._apply_transform(torch.zeros(state.shape)).shape
            observation_spec[out_key] = Bounded(
                0, 255, shape=shape, dtype=torch.uint8, device=state.device
            )
        return observation_spec
