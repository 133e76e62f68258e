"""Learning from pixels: the env's rendered frames through TorchRL's image transforms.

The PyTorch DQN tutorial first learnt CartPole from "the difference between the current and
previous screen patches". Here the frames come from TorchRL's ``GymWrapper(from_pixels=True,
pixels_only=True)`` (the state vector is dropped), then TorchRL transforms:

:class:`CropFrame` (a band of rows and columns of the ``[H, W, 3]`` uint8 frame, first so
that the rest touch only the patch), ``ToTensorImage`` (``[3, h, w]`` float, values kept in
0-255), ``GrayScale`` (``[1, h, w]``), :class:`PoolImage` (averaged over ``pool x pool``
blocks, back to uint8) and ``CatFrames`` (the last ``frames`` patches stacked: ``[frames, h /
pool, w / pool]``, the motion a single frame cannot show).

The pixels stay uint8 to the replay buffer (a quarter of float32) and become floats in
[0, 1] in the network's first layer (:class:`ScaleImage`). TorchRL's own ``Resize`` and
``Crop`` call torchvision, whose CPU build this project cannot install beside torch's CPU
wheel from PyPI (PyPI's torchvision is built for CUDA torch and fails to load its operators);
:class:`CropFrame` slices and :class:`PoolImage` uses ``torch.nn.functional.avg_pool2d``.

For CartPole the same pooled frame can be drawn from a batch of states at once instead
(:func:`drawn_pixel_transforms`, :mod:`trl_cartpole.envs.cartpole_drawing`): one call for
every env of a Gymnasium vector env, no pygame, except for a share of the envs painted with
Gymnasium's own pygame calls.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn
from torchrl.data.tensor_specs import Bounded, TensorSpec
from torchrl.envs.transforms import (
    CatFrames,
    ExcludeTransform,
    GrayScale,
    ObservationTransform,
    ToTensorImage,
    Transform,
)

from trl_cartpole.compat import set_missing_tolerance
from trl_cartpole.envs.cartpole_drawing import DrawCartPole

__all__ = [
    "PIXELS_KEY",
    "CropFrame",
    "PoolImage",
    "RandomShift",
    "ScaleImage",
    "drawn_pixel_transforms",
    "pixel_transforms",
]

PIXELS_KEY = "pixels"


class _ImageTransform(ObservationTransform):
    """An observation transform of ``pixels`` whose output spec is its output on zeros."""

    def __init__(self, in_keys: Sequence[str] = (PIXELS_KEY,)):
        super().__init__(in_keys=list(in_keys), out_keys=list(in_keys))

    def _reset(self, tensordict, tensordict_reset):
        with set_missing_tolerance(self, True):
            return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: TensorSpec) -> TensorSpec:
        for key in self.in_keys:
            spec = observation_spec[key]
            out = self._apply_transform(torch.zeros(spec.shape, dtype=spec.dtype))
            observation_spec[key] = Bounded(
                0, 255, shape=out.shape, dtype=out.dtype, device=spec.device
            )
        return observation_spec


class CropFrame(_ImageTransform):
    """Keep rows ``[top, bottom)`` and columns ``[left, right)`` of a ``[*B, H, W, C]`` frame
    (``None``: up to the edge). First, so that the later transforms touch only the patch."""

    def __init__(self, crop: Sequence[int | None], in_keys: Sequence[str] = (PIXELS_KEY,)):
        super().__init__(in_keys)
        self.top, self.bottom, self.left, self.right = crop

    def _apply_transform(self, frame: torch.Tensor) -> torch.Tensor:
        return frame[..., self.top : self.bottom, self.left : self.right, :]


class PoolImage(_ImageTransform):
    """Average a ``[*B, C, H, W]`` image (floats in 0-255) over ``pool x pool`` blocks and round
    it to uint8: ``[*B, C, H // pool, W // pool]``. Area averaging keeps a thin pole visible
    where a nearest-pixel downscale can drop it."""

    def __init__(self, pool: int, in_keys: Sequence[str] = (PIXELS_KEY,)):
        super().__init__(in_keys)
        self.pool = pool

    def _apply_transform(self, image: torch.Tensor) -> torch.Tensor:
        lead = image.shape[:-3]
        flat = image.reshape(-1, *image.shape[-3:]).float()  # [N, C, H, W]
        if self.pool > 1:
            flat = nn.functional.avg_pool2d(flat, self.pool)  # [N, C, H // pool, W // pool]
        return flat.round().clamp(0, 255).to(torch.uint8).reshape(*lead, *flat.shape[-3:])


class RandomShift(Transform):
    """DrQ's augmentation (Kostrikov, Yarats and Fergus 2020, "Image Augmentation Is All You
    Need"): each ``[C, H, W]`` image of a sampled batch is padded by ``pad`` pixels (its edge
    repeated) and cropped back to ``H x W`` at a random offset, i.e. shifted by up to ``pad``
    pixels each way. A replay buffer's transform: it runs on samples, never on what is stored;
    the frames now and next are shifted independently, as in DrQ."""

    def __init__(
        self, pad: int = 1, in_keys: Sequence = (PIXELS_KEY, ("next", PIXELS_KEY))
    ) -> None:
        super().__init__(in_keys=list(in_keys), out_keys=list(in_keys))
        self.pad = pad

    def _apply_transform(self, pixels: torch.Tensor) -> torch.Tensor:
        """Shift each image by its own offset: pixel (y, x) of the result is the image's
        (clamp(y + top - pad), clamp(x + left - pad)), which is the edge-repeating pad and the
        crop at (top, left), read from the uint8 image directly (about a tenth of the time of
        padding a float copy and slicing it image by image, bitwise the same; tested)."""
        images = pixels.reshape(-1, *pixels.shape[-3:])  # [N, C, H, W]
        count, channels, height, width = images.shape
        device = pixels.device
        offsets = torch.randint(0, 2 * self.pad + 1, (2, count), device=device)  # top, left
        first = torch.arange(count, device=device)[:, None]  # [N, 1]
        rows = torch.arange(height, device=device) + offsets[0, :, None] - self.pad  # [N, H]
        cols = torch.arange(width, device=device) + offsets[1, :, None] - self.pad  # [N, W]
        rows = rows.clamp_(0, height - 1) + first * height  # rows of [N * H]
        by_rows = (  # [C, N * H, W] -> [N, C, H, W]: each image's rows, shifted
            images.transpose(0, 1)
            .reshape(channels, count * height, width)
            .index_select(1, rows.reshape(-1))
            .reshape(channels, count, height, width)
            .transpose(0, 1)
        )
        cols = cols.clamp_(0, width - 1)[:, None, None, :].expand(count, channels, height, width)
        return by_rows.gather(3, cols).reshape(pixels.shape)  # and its columns


class ScaleImage(nn.Module):
    """``[*B, C, H, W]`` uint8 pixels -> float32 in [0, 1]: the network's first step, so that
    the replay buffer keeps uint8."""

    def forward(self, pixels: torch.Tensor) -> torch.Tensor:
        return pixels.float() / 255.0


def pixel_transforms(
    crop: Sequence[int | None] = (None, None, None, None), pool: int = 1, frames: int = 1
) -> list[Transform]:
    """TorchRL transforms from a ``GymWrapper(from_pixels=True)`` frame ``[H, W, 3]`` uint8 to
    the network's input ``[frames, h, w]`` uint8 (module docstring)."""
    transforms: list[Transform] = [
        CropFrame(crop),  # [h0, w0, 3] uint8
        ToTensorImage(from_int=False, in_keys=[PIXELS_KEY]),  # [3, h0, w0] float, 0-255
        GrayScale(in_keys=[PIXELS_KEY]),  # [1, h0, w0]
        PoolImage(pool),  # [1, h0 // pool, w0 // pool] uint8
    ]
    if frames > 1:
        transforms.append(CatFrames(N=frames, dim=-3, in_keys=[PIXELS_KEY]))  # [frames, h, w]
    return transforms


def drawn_pixel_transforms(
    crop: Sequence[int | None] = (None, None, None, None),
    pool: int = 1,
    frames: int = 1,
    length: float = 0.5,
    x_threshold: float = 2.4,
    rendered: int = 0,
) -> list[Transform]:
    """TorchRL transforms from a CartPole state env to the same ``[frames, h, w]`` uint8 input
    :func:`pixel_transforms` gives from ``render()``: :class:`DrawCartPole` (its first
    ``rendered`` envs rendered by Gymnasium), ``CatFrames``, and ``ExcludeTransform`` of the
    state, so the policy sees pixels only."""
    draw = DrawCartPole(crop, pool, length, x_threshold, rendered=rendered)
    transforms: list[Transform] = [draw]  # [1, h, w]
    if frames > 1:
        transforms.append(CatFrames(N=frames, dim=-3, in_keys=[PIXELS_KEY]))  # [frames, h, w]
    transforms.append(ExcludeTransform("observation"))
    return transforms
