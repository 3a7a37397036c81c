"""Paired random transforms: one parameter draw moves RGB, depth and intrinsics together.

Following pix2pix's ``get_params`` idea, the random numbers are drawn once into a
``TransformParams`` and then applied to every part of the frame, so RGB and
depth never drift apart and the intrinsics stay true to the pixels:
a resize scales fx, fy, cx, cy; a crop shifts cx, cy; a flip mirrors cx.
Depth is resized with nearest neighbour so holes never blend into valid depth.
A zoom keeps depth, as a longer lens would: the frame is never scaled below the
size that fills the crop, so every training pixel is a real one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from PIL import Image

from recordings.frames import Frame
from trainer.config import TransformConfig


@dataclass(frozen=True)
class TransformParams:
    resize: tuple[int, int]  # (height, width) after scaling
    crop: tuple[int, int, int, int]  # top, left, height, width
    flip: bool
    brightness: float
    contrast: float
    saturation: float


def crop_size(rng: np.random.Generator, config: TransformConfig, multiple: int) -> tuple[int, int]:
    """One batch's crop (height, width): ``size``, or a narrower view drawn from ``extent``, on the network's grid."""
    height, width = config.size
    if rng.random() < config.whole_share:
        return height, width
    extent = rng.uniform(*config.extent)
    return tuple(max(multiple, int(side * extent) // multiple * multiple) for side in (height, width))


def sample_params(
    rng: np.random.Generator, config: TransformConfig, height: int, width: int, crop: tuple[int, int] | None = None
) -> TransformParams:
    """One frame's draw; ``crop`` (default ``config.size``) is the window taken from the resized frame."""
    crop_h, crop_w = crop or config.size
    scale = max(rng.uniform(*config.scale), crop_h / height, crop_w / width)  # never smaller than the crop
    new_h, new_w = max(crop_h, math.ceil(height * scale)), max(crop_w, math.ceil(width * scale))
    top = int(rng.integers(0, new_h - crop_h + 1))
    left = int(rng.integers(0, new_w - crop_w + 1))

    def factor(amount: float) -> float:
        return float(rng.uniform(1 - amount, 1 + amount)) if amount else 1.0

    flip = bool(config.flip and rng.random() < 0.5)
    brightness, contrast, saturation = (factor(a) for a in (config.brightness, config.contrast, config.saturation))
    return TransformParams(
        resize=(new_h, new_w),
        crop=(top, left, crop_h, crop_w),
        flip=flip,
        brightness=brightness,
        contrast=contrast,
        saturation=saturation,
    )


def resize_frame(frame: Frame, height: int, width: int) -> Frame:
    """Area-like bilinear for RGB, nearest for depth, intrinsics scaled to match."""
    if (height, width) == frame.depth.shape:
        return frame
    rgb = np.asarray(Image.fromarray(frame.rgb).resize((width, height), Image.Resampling.BILINEAR))
    depth = np.asarray(Image.fromarray(frame.depth, mode="F").resize((width, height), Image.Resampling.NEAREST))
    return Frame(rgb, depth.astype(np.float32), frame.intrinsics.resized(width, height), frame.name)


def jitter_colour(rgb: np.ndarray, brightness: float, contrast: float, saturation: float) -> np.ndarray:
    x = rgb.astype(np.float32) * brightness
    grey = x @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    x = (x - grey.mean()) * contrast + grey.mean()
    grey = (x @ np.array([0.299, 0.587, 0.114], dtype=np.float32))[..., None]
    x = grey + (x - grey) * saturation
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def apply_params(frame: Frame, p: TransformParams) -> Frame:
    frame = resize_frame(frame, *p.resize)
    top, left, h, w = p.crop
    rgb = frame.rgb[top : top + h, left : left + w]
    depth = frame.depth[top : top + h, left : left + w]
    intrinsics = frame.intrinsics.cropped(left, top, w, h)
    if p.flip:
        rgb, depth, intrinsics = rgb[:, ::-1], depth[:, ::-1], intrinsics.flipped()
    rgb = jitter_colour(rgb, p.brightness, p.contrast, p.saturation)
    return Frame(np.ascontiguousarray(rgb), np.ascontiguousarray(depth), intrinsics, frame.name)
