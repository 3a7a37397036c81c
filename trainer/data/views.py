"""Rendered views: a train frame seen from a nearby camera, through its own depth and camera.

A fit's recording shows its room from the paths the recorder walked; a live camera goes
elsewhere, most often closer to things. Each train frame's depth, back-projected with its own
pinhole camera, is a coloured point set that can be looked at from a moved camera: forward
toward near objects, back, sideways and turned. The view is rendered at the recording's
resolution, before the training transform shrinks it to the working scale, so a view moved
forward is as sharp as a real near view would be (a magnified patch of a shrunk photo would
teach "blurry means near").

- The nearest point wins each pixel (a z-buffer). A point that comes nearer covers more pixels:
  its square splat is as wide as its magnification (1 to 3 pixels), so a near surface stays
  closed instead of showing the background through its gaps.
- The depth target keeps only the pixels a point landed on; every other pixel is 0, which the
  training loss never scores. Holes in the photo (disocclusions, the frame's edges after a move
  back, pixels the sensor had no depth for) are filled by OpenCV's inpainting, only so the
  network sees a photo without black holes.
- A view is rendered at no more than twice the width and height the training transform keeps of its frame
  (the recording's full resolution for 640x480): a view moved forward by the most ``forward`` allows (45%
  of the median depth) is magnified up to 1.8x, so it stays as sharp as the frames, and a large
  recording's bank costs no more than a small one's.
- The views are rendered once, before training, into a bank beside the run's checkpoints
  (``views/``: PNG pairs and a CSV manifest): a step reads them from disk as it reads any frame, so no step
  waits on a render, and ``--resume`` finds the bank already made.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from contract.geometry import Intrinsics
from recordings.frames import WRITTEN_DEPTH_SCALE, Frame, FrameReader, RecordedPair
from recordings.manifest import ManifestReader, write_manifest
from trainer.config import RenderedViews, TransformConfig
from trainer.data.transforms import resize_frame

#: Points nearer the moved camera than this (metres) are behind or inside it: never drawn.
NEAR_CLIP_M = 0.05
#: The widest splat, in pixels: a point magnified more than this leaves gaps (holes, never scored).
MAX_SPLAT = 3
#: The inpainting radius in pixels (``cv2.inpaint``'s ``inpaintRadius``).
INPAINT_RADIUS = 3
#: Views are rendered at this many times the largest scale the training transform draws (at most the
#: recording's own size): more than the 1.8x that the farthest forward move magnifies a frame by.
OVERSAMPLING = 2.0


@dataclass(frozen=True)
class Motion:
    """Where the rendered view's camera is: a rotation and a translation of the frame's camera.

    A point ``X`` in the frame's camera coordinates (x right, y down, z forward, metres) is
    ``rotation @ (X - centre)`` in the moved camera's: ``centre`` is the moved camera's position
    in the frame's camera coordinates, and ``rotation`` turns the frame's axes into the new ones.
    """

    rotation: np.ndarray  # 3x3
    centre: np.ndarray  # 3

    @staticmethod
    def still() -> Motion:
        return Motion(np.eye(3), np.zeros(3))


def rotation_from_angles(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """The rotation of a camera turned by ``yaw`` (about y), ``pitch`` (about x) and ``roll`` (about z).

    The matrix maps the frame camera's coordinates into the turned camera's, so a camera turned
    right by yaw sees a point straight ahead of the frame's camera to its left.
    """
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    turn = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
    tilt = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    spin = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    camera_to_frame = turn @ tilt @ spin  # the turned camera's axes, in the frame camera's coordinates
    return camera_to_frame.T


def sample_motion(rng: np.random.Generator, median_depth_m: float, settings: RenderedViews) -> Motion:
    """A nearby camera: forward or back along the view, sideways and up or down, turned a little.

    Distances are shares of the frame's median depth, so a view of a far wall and one of a desk
    move by the same share of what they see.
    """
    forward = rng.uniform(-settings.back, settings.forward) * median_depth_m
    side, up = rng.uniform(-settings.sideways, settings.sideways, 2) * median_depth_m
    yaw, pitch = rng.uniform(-settings.turn_deg, settings.turn_deg, 2)
    roll = rng.uniform(-settings.roll_deg, settings.roll_deg)
    return Motion(rotation_from_angles(yaw, pitch, roll), np.array([side, up, forward]))


def render_view(frame: Frame, motion: Motion) -> tuple[Frame, np.ndarray]:
    """``frame`` seen from the camera ``motion`` puts it at, with the same intrinsics and size.

    Returns the view (holes in its depth are 0, its photo inpainted there) and the boolean mask of
    the pixels a point landed on.
    """
    k = frame.intrinsics
    height, width = frame.depth.shape
    rows, cols = np.nonzero(frame.depth > 0)
    z = frame.depth[rows, cols]
    x = (cols.astype(np.float32) - np.float32(k.cx)) * (z / np.float32(k.fx))
    y = (rows.astype(np.float32) - np.float32(k.cy)) * (z / np.float32(k.fy))
    # Each moved coordinate written out: a 3x3 product over N points costs more through BLAS on 2 cores.
    r, c = motion.rotation.astype(np.float32), motion.centre.astype(np.float32)
    x, y, zc = x - c[0], y - c[1], z - c[2]
    new_z = r[2, 0] * x + r[2, 1] * y + r[2, 2] * zc
    ahead = np.nonzero(new_z > NEAR_CLIP_M)[0]
    new_x = (r[0, 0] * x + r[0, 1] * y + r[0, 2] * zc)[ahead]
    new_y = (r[1, 0] * x + r[1, 1] * y + r[1, 2] * zc)[ahead]
    new_z, z, colours = new_z[ahead], z[ahead], frame.rgb[rows[ahead], cols[ahead]]
    u = k.fx * new_x / new_z + k.cx
    v = k.fy * new_y / new_z + k.cy
    # A point brought nearer is magnified by z / new_z: its splat grows so the surface stays closed.
    size = np.clip(np.ceil(z / new_z - 1e-6), 1, MAX_SPLAT).astype(np.int64)
    first_u = np.rint(u - (size - 1) / 2).astype(np.int64)
    first_v = np.rint(v - (size - 1) / 2).astype(np.int64)
    pixel_parts, point_parts = [], []
    for dv in range(MAX_SPLAT):
        for du in range(MAX_SPLAT):
            covers = np.nonzero(size > max(du, dv))[0]
            pu, pv = first_u[covers] + du, first_v[covers] + dv
            inside = (pu >= 0) & (pu < width) & (pv >= 0) & (pv < height)
            pixel_parts.append(pv[inside] * width + pu[inside])
            point_parts.append(covers[inside])
    pixel, point = np.concatenate(pixel_parts), np.concatenate(point_parts)
    # The z-buffer: each pixel keeps the smallest key, its depth in micrometres above the point's index,
    # so the nearest point wins (the lower index on a tie), in one pass.
    bits = max(1, len(new_z).bit_length())
    keys = (np.rint(new_z.astype(np.float64) * 1e6).astype(np.int64) << bits) | np.arange(len(new_z))
    keys = keys[point]
    nearest = np.full(height * width, np.iinfo(np.int64).max)
    np.minimum.at(nearest, pixel, keys)
    pixel = np.nonzero(nearest != np.iinfo(np.int64).max)[0]
    point = nearest[pixel] & ((1 << bits) - 1)

    depth = np.zeros(height * width, dtype=np.float32)
    depth[pixel] = new_z[point]
    rgb = np.zeros((height * width, 3), dtype=np.uint8)
    rgb[pixel] = colours[point]
    landed = np.zeros(height * width, dtype=bool)
    landed[pixel] = True
    landed = landed.reshape(height, width)
    rgb = rgb.reshape(height, width, 3)
    if not landed.all():
        rgb = cv2.inpaint(rgb, (~landed).astype(np.uint8), INPAINT_RADIUS, cv2.INPAINT_TELEA)
    view = Frame(rgb, depth.reshape(height, width), frame.intrinsics, frame.name)
    return view, landed


def view_rng(seed: int, frame_index: int, view: int) -> np.random.Generator:
    """The draw of one view's motion: the bank is the same for the same seed, whatever renders it."""
    return np.random.default_rng([seed, frame_index, view, 3])


@dataclass(frozen=True)
class ViewBank:
    """The rendered views of the train frames, ``per_frame`` each: view ``j`` of frame ``i`` is ``view(i, j)``."""

    reader: FrameReader
    per_frame: int
    #: Milliseconds a view took to render (NaN where the bank was found made).
    render_ms: float
    #: The views' size as a share of their frames' (1: rendered at the recording's resolution).
    scale: float = 1.0

    def view(self, frame_index: int, j: int) -> Frame:
        return self.reader[frame_index * self.per_frame + j]


def view_bank(frames: FrameReader, settings: RenderedViews, seed: int, folder: Path, scale: float = 1.0) -> ViewBank:
    """The bank of rendered views in ``folder``: made now, or found made by the same frames and settings.

    Each frame is shrunk to ``scale`` of its size (area-like for the photo, nearest for depth) and rendered there.
    """
    key = {
        "settings": settings.model_dump(mode="json"),
        "seed": seed,
        "frames": [frames[0].name, len(frames)],
        "scale": scale,
    }
    manifest, record = folder / "views.csv", folder / "views.json"
    if manifest.is_file() and record.is_file():
        made = json.loads(record.read_text())
        if made["key"] == key:
            return ViewBank(ManifestReader(manifest), settings.per_frame, float("nan"), scale)
    folder.mkdir(parents=True, exist_ok=True)
    pairs: list[RecordedPair] = []
    began = time.perf_counter()
    for i in range(len(frames)):
        frame = frames[i]
        if scale < 1:
            height, width = frame.depth.shape
            frame = resize_frame(frame, max(1, round(height * scale)), max(1, round(width * scale)))
        valid = frame.depth[frame.depth > 0]
        median = float(np.median(valid)) if valid.size else 0.0
        for j in range(settings.per_frame):
            motion = sample_motion(view_rng(seed, i, j), median, settings) if median else Motion.still()
            view, _ = render_view(frame, motion)
            pairs.append(_write_view(view, folder, f"{i:05d}-{j}"))
    ms = (time.perf_counter() - began) * 1000 / max(1, len(pairs))
    write_manifest(manifest, pairs)
    record.write_text(json.dumps({"key": key, "views": len(pairs), "render_ms": round(ms, 1)}, indent=1))
    return ViewBank(ManifestReader(manifest), settings.per_frame, ms, scale)


def render_scale(transform: TransformConfig) -> float:
    """The share of a frame's size its views are rendered at: ``OVERSAMPLING`` times the largest scale the
    training transform draws, and never above the recording's own."""
    return min(1.0, OVERSAMPLING * max(transform.scale))


def _write_view(view: Frame, folder: Path, stem: str) -> RecordedPair:
    """One view as a PNG pair (colour, and depth in millimetres; 0 is a hole)."""
    rgb, depth = folder / f"{stem}.color.png", folder / f"{stem}.depth.png"
    Image.fromarray(view.rgb).save(rgb, compress_level=1)
    millimetres = np.clip(np.rint(view.depth * WRITTEN_DEPTH_SCALE), 0, 65534).astype(np.uint16)
    Image.fromarray(millimetres).save(depth, compress_level=1)
    k: Intrinsics = view.intrinsics
    return RecordedPair(stem, rgb, depth, WRITTEN_DEPTH_SCALE, k)
