"""Held-out view novelty from camera poses: known geometry, and the command on a tiny sequence."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO, run_cli

from lab.novelty import read_poses, view_novelty


def _pose(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    """Camera at (x, 0, 0), turned about the vertical axis by ``yaw_deg``."""
    t = np.radians(yaw_deg)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(t), 0, np.sin(t)], [0, 1, 0], [-np.sin(t), 0, np.cos(t)]]
    pose[0, 3] = x
    return pose


def test_a_moved_camera_and_a_turned_camera_are_measured_apart():
    train = np.stack([_pose(0.0), _pose(5.0, 90.0)])
    moved = view_novelty(train, np.stack([_pose(0.5)]))
    assert (moved.distance_m, moved.angle_deg) == pytest.approx((0.5, 0.0))
    # Standing on the first camera's spot but facing the second's way: 0 m + 90/30 beats 5 m + 0 deg.
    turned = view_novelty(train, np.stack([_pose(0.0, 90.0)]))
    assert (turned.distance_m, turned.angle_deg) == pytest.approx((0.0, 90.0))
    assert view_novelty(train, train).distance_m == 0.0


def test_the_command_reads_7scenes_pose_files(tmp_path):
    for n, x in enumerate([0.0, 0.1, 0.2, 1.2]):
        np.savetxt(tmp_path / f"frame-{n:06d}.pose.txt", _pose(x))
    assert read_poses(tmp_path, "0-1").shape == (2, 4, 4)
    table = run_cli("novelty", str(tmp_path), "0-1:2", "0-1:3", package="lab").stdout
    assert "| 0-1 | 2 | 1 | 0.10 | 0.0 |" in table and "| 0-1 | 3 | 1 | 1.10 | 0.0 |" in table
    bad = subprocess.run(
        [sys.executable, "-m", "lab", "novelty", str(tmp_path), "0-1:2", "0-1"],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert bad.returncode != 0 and "TRAIN:HELD_OUT" in bad.stderr
    assert bad.stdout == ""  # checked before any row is printed
    with pytest.raises(FileNotFoundError, match="no pose file"):
        read_poses(tmp_path, "0-4")
