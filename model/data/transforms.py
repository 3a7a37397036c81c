"""Paired random transforms: one parameter draw moves RGB, depth and intrinsics together.

Following pix2pix's ``get_params`` idea, the random numbers are drawn once into a
``TransformParams`` and then applied to every part of the frame, so RGB and
depth never drift apart and the intrinsics stay true to the pixels:
a resize scales fx, fy, cx, cy; a crop shifts cx, cy; a flip mirrors cx.
Depth is resized with nearest neighbour so holes never blend into valid depth.

With ``zoom_depth`` a zoom is not a longer lens but a step closer (Eigen et al.
2014's scale augmentation): a frame enlarged z times beyond the scale that just
fills the crop gets depth / z and focal lengths / z, so that the size an object
appears at keeps meaning the same distance. It is exact for a plane facing the
camera, and it widens the range of distances one recording shows. On 7-Scenes it
moves how far new views are judged, but as a shift towards "closer": enlargements of
1-1.5 put both validation folds' views too close (recipe step 15), and 1-1.2 set the
folds nearly right but the test views, already right without it, 7% too close (step
16). So the default recipe leaves it off. ``zoom_out`` lets a scale below the crop-filling
one shrink the frame inside black, depth-less borders, so that with ``zoom_depth`` steps
back can balance the steps closer and a place's average distance stays what it is.

A virtual camera turn (``rotate_deg``) shows the room from viewing directions
the recording never took. A pure rotation has no parallax, so it is exact: RGB and
depth move by the homography K R^T K^-1, and each depth is re-measured along the
new optical axis. Pixels the old view never saw become black with no depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from PIL import Image

from model.config import TransformConfig
from model.data.frames import Frame
from model.geometry import ray_factors


@dataclass(frozen=True)
class TransformParams:
    resize: tuple[int, int]  # (height, width) after scaling
    crop: tuple[int, int, int, int]  # top, left, height, width
    flip: bool
    brightness: float
    contrast: float
    saturation: float
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)  # yaw, pitch, roll in degrees
    closer: float = 1.0  # depth and focal lengths are divided by this (``zoom_depth``); < 1 is a step back


def sample_params(rng: np.random.Generator, config: TransformConfig, height: int, width: int) -> TransformParams:
    crop_h, crop_w = config.size
    scale = rng.uniform(*config.scale)
    fills_crop = max(crop_h / height, crop_w / width)
    if config.zoom_out:  # a frame smaller than the crop sits inside borders: negative offsets
        new_h, new_w = math.ceil(height * scale), math.ceil(width * scale)
    else:  # never smaller than the crop
        scale = max(scale, fills_crop)
        new_h, new_w = max(crop_h, math.ceil(height * scale)), max(crop_w, math.ceil(width * scale))
    top = int(rng.integers(min(0, new_h - crop_h), max(0, new_h - crop_h) + 1))
    left = int(rng.integers(min(0, new_w - crop_w), max(0, new_w - crop_w) + 1))

    def factor(amount: float) -> float:
        return float(rng.uniform(1 - amount, 1 + amount)) if amount else 1.0

    flip = bool(config.flip and rng.random() < 0.5)
    brightness, contrast, saturation = (factor(a) for a in (config.brightness, config.contrast, config.saturation))
    # Drawn last, and only when on, so that configs without it keep their random stream.
    turn = rng.uniform(-config.rotate_deg, config.rotate_deg, 3) if config.rotate_deg else np.zeros(3)
    return TransformParams(
        resize=(new_h, new_w),
        crop=(top, left, crop_h, crop_w),
        flip=flip,
        brightness=brightness,
        contrast=contrast,
        saturation=saturation,
        rotation=tuple(float(a) for a in turn),
        closer=scale / fills_crop if config.zoom_depth else 1.0,
    )


def rotation_matrix(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Camera turn in degrees: yaw about y (down), pitch about x (right), roll about z (forward)."""
    y, p, r = np.radians([yaw, pitch, roll])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return rz @ rx @ ry


def rotate_frame(frame: Frame, rotation: np.ndarray) -> Frame:
    """The frame as the same camera would see it after turning by ``rotation`` (new = R @ old).

    For each new pixel p', the old view saw its ray along d = R^T K^-1 p'; the RGB is
    sampled bilinearly there, the depth by nearest neighbour (no blending across
    holes), and a point at old depth z lies at new depth z / d_z.
    """
    k = frame.intrinsics
    h, w = frame.depth.shape
    x, y = ray_factors(k)
    grid = np.stack(np.broadcast_arrays(x[None, :], y[:, None], np.float32(1.0)), -1)
    rays = grid @ rotation  # rows: R^T p
    dz = rays[..., 2]
    ahead = dz > 1e-6
    dz_safe = np.where(ahead, dz, 1.0)
    su = np.where(ahead, rays[..., 0] / dz_safe * k.fx + k.cx, -1.0)
    sv = np.where(ahead, rays[..., 1] / dz_safe * k.fy + k.cy, -1.0)

    inside = (su > -0.5) & (su < w - 0.5) & (sv > -0.5) & (sv < h - 0.5)  # its nearest old pixel exists
    ni = np.clip(np.rint(sv), 0, h - 1).astype(np.intp)
    nj = np.clip(np.rint(su), 0, w - 1).astype(np.intp)
    depth = np.where(inside, frame.depth[ni, nj] / dz_safe, 0.0).astype(np.float32)

    u0 = np.clip(np.floor(su), 0, w - 2).astype(np.intp)
    v0 = np.clip(np.floor(sv), 0, h - 2).astype(np.intp)
    fu = np.clip(su - u0, 0, 1)[..., None]
    fv = np.clip(sv - v0, 0, 1)[..., None]
    src = frame.rgb.astype(np.float64)
    top = src[v0, u0] * (1 - fu) + src[v0, u0 + 1] * fu
    bottom = src[v0 + 1, u0] * (1 - fu) + src[v0 + 1, u0 + 1] * fu
    rgb = np.where(inside[..., None], top * (1 - fv) + bottom * fv, 0.0)
    return Frame(np.rint(rgb).astype(np.uint8), depth, k, frame.name)


def resize_frame(frame: Frame, height: int, width: int) -> Frame:
    """Area-like bilinear for RGB, nearest for depth, intrinsics scaled to match."""
    if (height, width) == frame.depth.shape:
        return frame
    rgb = np.asarray(Image.fromarray(frame.rgb).resize((width, height), Image.Resampling.BILINEAR))
    depth = np.asarray(Image.fromarray(frame.depth, mode="F").resize((width, height), Image.Resampling.NEAREST))
    return Frame(rgb, depth.astype(np.float32), frame.intrinsics.resized(width, height), frame.name)


def pad_frame(frame: Frame, top: int, bottom: int, left: int, right: int) -> Frame:
    """The frame inside black, depth-less borders; the camera's centre moves with the image."""
    h, w = frame.depth.shape
    rgb = np.pad(frame.rgb, ((top, bottom), (left, right), (0, 0)))
    depth = np.pad(frame.depth, ((top, bottom), (left, right)))
    return Frame(rgb, depth, frame.intrinsics.cropped(-left, -top, w + left + right, h + top + bottom), frame.name)


def jitter_colour(rgb: np.ndarray, brightness: float, contrast: float, saturation: float) -> np.ndarray:
    x = rgb.astype(np.float32) * brightness
    grey = x @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    x = (x - grey.mean()) * contrast + grey.mean()
    grey = (x @ np.array([0.299, 0.587, 0.114], dtype=np.float32))[..., None]
    x = grey + (x - grey) * saturation
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def apply_params(frame: Frame, p: TransformParams) -> Frame:
    frame = resize_frame(frame, *p.resize)
    if any(p.rotation):
        frame = rotate_frame(frame, rotation_matrix(*p.rotation))
    top, left, h, w = p.crop
    frame_h, frame_w = frame.depth.shape
    below, right = max(0, top + h - frame_h), max(0, left + w - frame_w)
    if top < 0 or left < 0 or below or right:  # zoom_out: the crop reaches past the shrunken frame
        frame = pad_frame(frame, max(0, -top), below, max(0, -left), right)
        top, left = max(0, top), max(0, left)
    rgb = frame.rgb[top : top + h, left : left + w]
    depth = frame.depth[top : top + h, left : left + w]
    intrinsics = frame.intrinsics.cropped(left, top, w, h)
    if p.flip:
        rgb, depth, intrinsics = rgb[:, ::-1], depth[:, ::-1], intrinsics.flipped()
    if p.closer != 1.0:
        depth = depth / np.float32(p.closer)  # holes (0) stay holes
        intrinsics = replace(intrinsics, fx=intrinsics.fx / p.closer, fy=intrinsics.fy / p.closer)
    rgb = jitter_colour(rgb, p.brightness, p.contrast, p.saturation)
    return Frame(np.ascontiguousarray(rgb), np.ascontiguousarray(depth), intrinsics, frame.name)
