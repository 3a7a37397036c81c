"""How new held-out camera views are to a model, from 7-Scenes camera poses.

A validation slice predicts test scores only if its views are as new to the model as
the test views are. Frames taken right after the training frames look almost the same
(the camera has barely moved), so they reward memorising neighbours; test frames far
along the path show the room from new places. This module measures that gap, so a
validation slice can be chosen to match the test split before anything is trained.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.errors import UserError
from recordings.frames import parse_frame_ranges

#: A turn of this many degrees counts like one metre of camera travel when picking the
#: closest training view; roughly where a Kinect view of a room stops overlapping much.
DEGREES_PER_METRE = 30.0


@dataclass(frozen=True)
class Novelty:
    """Medians over the held-out frames of the gap to each one's closest training view."""

    frames: int
    distance_m: float
    angle_deg: float


def read_poses(root: Path, frames: str) -> np.ndarray:
    """The 4x4 camera-to-world poses (frame-NNNNNN.pose.txt) of the selected frames."""
    poses = []
    for number in parse_frame_ranges(frames):
        path = Path(root) / f"frame-{number:06d}.pose.txt"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no pose file")
        pose = np.loadtxt(path, dtype=np.float64)
        if pose.shape != (4, 4):
            raise UserError(f"{path}: expected a 4x4 pose, got shape {pose.shape}")
        poses.append(pose)
    return np.stack(poses)


def _angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (radians) between every row of ``a`` and of ``b``.

    The axes are normalised first (the published 7-Scenes rotations are not exactly
    orthonormal), and atan2 keeps near-identical directions at ~0 where arccos would not.
    """
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    cross = np.linalg.norm(np.cross(a[:, None], b[None]), axis=2)
    return np.arctan2(cross, a @ b.T)


def view_novelty(train: np.ndarray, held_out: np.ndarray) -> Novelty:
    """For each held-out view, the closest training view by metres + degrees / 30.

    Position and viewing direction are combined because either alone misleads: a camera
    on the same spot can look at another wall, and one pointing the same way can stand
    across the room.
    """
    distance = np.linalg.norm(held_out[:, None, :3, 3] - train[None, :, :3, 3], axis=2)
    angle = np.degrees(_angle_between(held_out[:, :3, 2], train[:, :3, 2]))  # optical axes (+z)
    closest = (distance + angle / DEGREES_PER_METRE).argmin(axis=1)
    rows = np.arange(len(held_out))
    return Novelty(
        frames=len(held_out),
        distance_m=float(np.median(distance[rows, closest])),
        angle_deg=float(np.median(angle[rows, closest])),
    )


def novelty_table(root: Path, splits: list[str]) -> str:
    """``rgb2cloud-lab novelty``: a Markdown table, one row per ``TRAIN:HELD_OUT`` pair of frame ranges."""
    pairs = [split.partition(":") for split in splits]
    for split, (train, sep, held_out) in zip(splits, pairs, strict=True):
        if not sep or not train or not held_out:
            raise UserError(f"{split!r}: expected TRAIN:HELD_OUT, e.g. 0-669:720-799")
    lines = [
        "| train | held out | frames | closest training view: distance (m) | turn (deg) |",
        "|---|---|---|---|---|",
    ]
    for train, _, held_out in pairs:
        gap = view_novelty(read_poses(root, train), read_poses(root, held_out))
        lines.append(f"| {train} | {held_out} | {gap.frames} | {gap.distance_m:.2f} | {gap.angle_deg:.1f} |")
    return "\n".join(lines)
