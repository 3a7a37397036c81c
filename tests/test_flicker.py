"""The flicker measure (``harness.flicker``) and the stream's temporal filter (``app.temporal``), by hand."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SEVEN_SCENES

from app.temporal import TemporalFilter
from contract.geometry import Intrinsics
from harness.flicker import moved_depth, pair_flicker, read_pose, sequence_flicker

K = Intrinsics(fx=100.0, fy=100.0, cx=20.0, cy=15.0, width=40, height=30)


def pose(x: float = 0.0, z: float = 0.0) -> np.ndarray:
    """Camera-to-world: a camera moved x metres right and z metres forward, not turned."""
    matrix = np.eye(4)
    matrix[0, 3], matrix[2, 3] = x, z
    return matrix


def test_a_wall_seen_from_10_cm_nearer_is_10_cm_nearer():
    wall = np.full((30, 40), 2.0)
    moved = moved_depth(wall, pose(), pose(z=0.1), K)
    seen = moved > 0
    np.testing.assert_allclose(moved[seen], 1.9)
    # Nearer, the wall looks 2 / 1.9 times as big: its points spread, leaving a pixel in about twenty
    # that none lands on (forward warping's gaps; the measure skips them as not seen in both).
    assert 0.85 < seen.mean() < 1.0
    flicker = pair_flicker(wall, np.full((30, 40), 1.9), pose(), pose(z=0.1), K)
    assert flicker.relative == pytest.approx(0.0, abs=1e-9) and flicker.scale == pytest.approx(1.0)


def test_a_point_moves_across_the_image_by_the_focal_length_times_the_baseline_over_depth():
    depth = np.zeros((30, 40))
    depth[15, 20] = 2.0  # the principal point, 2 m away
    moved = moved_depth(depth, pose(), pose(x=0.2), K)
    # The camera went 0.2 m right: the point is 0.2 m to its left, 100 * 0.2 / 2 = 10 pixels.
    (row,), (col,) = np.nonzero(moved)
    assert (row, col) == (15, 10) and moved[15, 10] == pytest.approx(2.0)


@pytest.mark.parametrize("step", [0.1, -0.1])
def test_the_nearest_surface_wins_where_two_land_on_one_pixel(step):
    """A near point (1 m) shifts 100 x 0.1 / 1 = 10 px and a far one (2 m) 5 px, so the two land on one pixel;
    stepping right the far one comes first in the scan, stepping left the near one: either way the near wins."""
    depth = np.zeros((30, 40))
    far, near = (25, 30) if step > 0 else (20, 15)
    depth[15, far], depth[15, near] = 2.0, 1.0
    moved = moved_depth(depth, pose(), pose(x=step), K)
    (col,) = {far - round(step * 50), near - round(step * 100)}  # both arrive at the same column
    assert np.count_nonzero(moved) == 1 and moved[15, col] == pytest.approx(1.0)


def test_a_steady_scale_error_is_no_flicker_but_one_that_changes_is():
    wall = np.full((30, 40), 2.0)
    steady = sequence_flicker([wall * 1.1, wall * 1.1, wall * 1.1], [pose()] * 3, K)
    assert steady.relative == pytest.approx(0.0) and steady.scale_jitter == pytest.approx(0.0)
    jumpy = sequence_flicker([wall, wall * 1.02, wall], [pose()] * 3, K)
    assert jumpy.scale_jitter == pytest.approx(np.sqrt((0.02**2 + (1 / 1.02 - 1) ** 2) / 2))


def test_the_real_poses_explain_the_sensor_s_own_depth_better_than_none():
    """7-Scenes' poses are camera-to-world: moving by them brings consecutive sensor frames closer than not
    moving at all or moving the wrong way, which is what makes the sensor a floor to measure against."""
    from PIL import Image

    frames = range(900, 906)
    poses = [read_pose(SEVEN_SCENES / f"frame-{n:06d}.pose.txt") for n in frames]
    depths = []
    for n in frames:
        mm = np.asarray(Image.open(SEVEN_SCENES / f"frame-{n:06d}.depth.png"), dtype=np.float64)
        depths.append(np.where(mm < 65535, mm / 1000, 0))
    kinect = Intrinsics(fx=585.0, fy=585.0, cx=320.0, cy=240.0, width=640, height=480)
    moved = sequence_flicker(depths, poses, kinect).relative
    unmoved = sequence_flicker(depths, [np.eye(4)] * len(poses), kinect).relative
    inverted = sequence_flicker(depths, [np.linalg.inv(p) for p in poses], kinect).relative
    assert moved < 0.7 * unmoved and moved < 0.7 * inverted


def test_the_temporal_filter_blends_where_frames_agree_and_starts_afresh_where_they_do_not():
    smoother = TemporalFilter(alpha=0.4, delta=0.05)
    first = np.array([[2.0, 2.0, 0.0, 2.0]], dtype=np.float32)
    np.testing.assert_array_equal(smoother.apply(first), first)
    # within 5%: blended 0.4 new + 0.6 old; a 25% step: taken as it is; a hole, or depth where there was none
    second = np.array([[2.05, 2.5, 1.0, 0.0]], dtype=np.float32)
    np.testing.assert_allclose(smoother.apply(second), [[0.4 * 2.05 + 0.6 * 2.0, 2.5, 1.0, 0.0]], rtol=1e-6)
    third = np.full((2, 4), 3.0, dtype=np.float32)  # another size: a new start
    np.testing.assert_array_equal(smoother.apply(third), third)
