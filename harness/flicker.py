"""How much depth flickers from frame to frame, measured against the camera's true motion.

Depth that holds still moves with the camera and nothing else. So each frame's depth is moved into
the next frame's camera with the ground-truth poses (back-projected, transformed rigidly, projected,
the nearest surface kept where several land on one pixel) and compared with the next frame's own
depth at the pixels both see. What is left over is flicker: the model changing its mind, not the
scene. The sensor's own depth, moved the same way, is the floor: its noise, the poses' error and the
pixels that change from one frame to the next.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.geometry import Intrinsics


def read_pose(path: Path) -> np.ndarray:
    """A 4x4 camera-to-world matrix in plain text (7-Scenes' ``frame-NNNNNN.pose.txt``)."""
    pose = np.loadtxt(path, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"{path}: expected a 4x4 pose, got shape {pose.shape}")
    return pose


def moved_depth(depth: np.ndarray, pose: np.ndarray, next_pose: np.ndarray, k: Intrinsics) -> np.ndarray:
    """``depth`` (metres, 0 = none) of a camera at ``pose`` as the camera at ``next_pose`` would see it.

    Every pixel with depth is back-projected, moved by ``next_pose⁻¹ · pose``, and projected to the nearest
    pixel; where several land on one pixel the nearest is kept. 0 where nothing lands.
    """
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[v, u].astype(np.float64)
    points = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z, np.ones_like(z)])
    moved = (np.linalg.inv(next_pose) @ pose @ points)[:3]
    ahead = moved[2] > 1e-6
    x, y, z = moved[:, ahead]
    col = np.rint(k.fx * x / z + k.cx).astype(np.int64)
    row = np.rint(k.fy * y / z + k.cy).astype(np.int64)
    inside = (col >= 0) & (col < k.width) & (row >= 0) & (row < k.height)
    nearest = np.full(k.height * k.width, np.inf)
    np.minimum.at(nearest, row[inside] * k.width + col[inside], z[inside])
    nearest[~np.isfinite(nearest)] = 0.0
    return nearest.reshape(k.height, k.width)


@dataclass(frozen=True)
class PairFlicker:
    """One pair of consecutive frames: the mean |d_next − d_moved| / d_moved over the pixels both see, the
    median d_next / d_moved (the pair's global scale change; 1 where the depth holds its scale), and the
    share of the frame both see."""

    relative: float
    scale: float
    overlap: float


def pair_flicker(depth: np.ndarray, next_depth: np.ndarray, pose: np.ndarray, next_pose: np.ndarray, k: Intrinsics):
    """``PairFlicker`` of one frame's depth moved into the next frame's camera against the next frame's depth."""
    moved = moved_depth(depth, pose, next_pose, k)
    both = (moved > 0) & np.isfinite(next_depth) & (next_depth > 0)
    if not both.any():
        raise ValueError("the two frames see no pixel in common")
    ratio = next_depth[both] / moved[both]
    return PairFlicker(float(np.mean(np.abs(ratio - 1))), float(np.median(ratio)), float(both.mean()))


@dataclass(frozen=True)
class Flicker:
    """A sequence's flicker: the pairs' mean relative difference, and the frame-to-frame jitter of the global
    scale (the RMS of each pair's scale change minus 1)."""

    relative: float
    scale_jitter: float
    pairs: int


def sequence_flicker(depths: list[np.ndarray], poses: list[np.ndarray], k: Intrinsics) -> Flicker:
    """``Flicker`` over consecutive frames of one sequence, each with its depth and camera-to-world pose."""
    pairs = [pair_flicker(depths[i], depths[i + 1], poses[i], poses[i + 1], k) for i in range(len(depths) - 1)]
    relative = float(np.mean([p.relative for p in pairs]))
    jitter = float(np.sqrt(np.mean([(p.scale - 1) ** 2 for p in pairs])))
    return Flicker(relative, jitter, len(pairs))
