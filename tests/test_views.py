"""Rendered views (trainer/data/views.py) against geometry worked out by hand.

The scene is a small pinhole camera (64x48, f = 50 px, principal point at the centre) looking
at a wall, or at a box in front of a wall. Each photo pixel's colour names where it came from
(red = 4 x column, green = 5 x row), so a rendered pixel says which point landed on it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from contract.geometry import Intrinsics
from recordings.frames import Frame
from trainer.config import RenderedViews
from trainer.data.views import Motion, render_view, rotation_from_angles, sample_motion, view_bank

WIDTH, HEIGHT, F = 64, 48, 50.0
CAMERA = Intrinsics(F, F, 31.5, 23.5, WIDTH, HEIGHT)


def scene(depth: np.ndarray) -> Frame:
    """A frame of ``depth`` whose colours name each pixel's column and row."""
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    rgb = np.stack([cols * 4, rows * 5, np.full_like(cols, 128)], axis=-1).astype(np.uint8)
    return Frame(rgb, depth.astype(np.float32), CAMERA, "scene")


def source_of(view: Frame) -> tuple[np.ndarray, np.ndarray]:
    """The column and row each rendered pixel's point came from, read from its colour."""
    return view.rgb[..., 0] / 4.0, view.rgb[..., 1] / 5.0


def wall(z: float) -> np.ndarray:
    return np.full((HEIGHT, WIDTH), z, dtype=np.float32)


def box_on_wall() -> np.ndarray:
    """A wall at 3 m with a 12 x 12 pixel box face at 1 m: rows 18-29, columns 26-37."""
    depth = wall(3.0)
    depth[18:30, 26:38] = 1.0
    return depth


def test_zero_motion_gives_the_frame_back_wherever_depth_is_valid() -> None:
    depth = np.random.default_rng(1).uniform(0.5, 4.0, (HEIGHT, WIDTH)).astype(np.float32)
    depth[5:9, 10:20] = 0  # no reading: not carried, a hole in the view
    frame = scene(depth)
    view, landed = render_view(frame, Motion.still())
    valid = depth > 0
    assert np.array_equal(landed, valid)
    assert np.array_equal(view.depth, depth)
    assert np.array_equal(view.rgb[valid], frame.rgb[valid])
    assert view.intrinsics == CAMERA


def test_a_wall_seen_from_closer_is_nearer_and_magnified_about_the_principal_point() -> None:
    # Forward by 0.5 m toward a wall at 2 m: every point is at 1.5 m, and a point at column u
    # lands at cx + (u - cx) * 2 / 1.5, so the pixel at column c shows the point from
    # cx + (c - cx) * 0.75 (the same for rows); a splat is up to 2 pixels wide (magnification 1.33),
    # so a pixel may show a point up to 0.75 source pixels from that.
    view, landed = render_view(scene(wall(2.0)), Motion(np.eye(3), np.array([0.0, 0.0, 0.5])))
    assert landed.all()  # magnified: no holes
    assert np.all(view.depth == 1.5)
    cols, rows = source_of(view)
    expected_cols = 31.5 + (np.arange(WIDTH) - 31.5) * 0.75
    expected_rows = 23.5 + (np.arange(HEIGHT) - 23.5) * 0.75
    assert np.abs(cols - expected_cols[None, :]).max() <= 0.75
    assert np.abs(rows - expected_rows[:, None]).max() <= 0.75
    # Column 3 of the view shows the point from column 31.5 - 28.5 * 0.75 = 10.125: column 10.
    assert cols[24, 3] == 10


def test_a_box_moved_sideways_shifts_by_its_parallax_and_the_nearer_surface_wins() -> None:
    # The camera 0.1 m to the right: a point at depth z moves left by f * 0.1 / z pixels,
    # 5 for the box (1 m) and 5/3 for the wall (3 m).
    view, landed = render_view(scene(box_on_wall()), Motion(np.eye(3), np.array([0.1, 0.0, 0.0])))
    cols, _ = source_of(view)
    # The box's face: columns 26-37 land on 21-32, at 1 m, though wall points from columns 23-34 land there too.
    assert np.all(view.depth[18:30, 21:33] == 1.0)
    assert np.array_equal(cols[18:30, 21:33], np.tile(np.arange(26, 38), (12, 1)))
    # Beside it, the wall moved by 5/3 pixels: column 20 shows the wall's column 20 + 1.667, i.e. 22.
    assert np.all(view.depth[:, 20] == 3.0)
    assert np.all(cols[:, 20] == 22)
    # Behind the box's right edge the wall was never seen: columns 33-35 of the box's rows are holes,
    # unscored (depth 0), their photo filled in.
    assert not landed[18:30, 33:36].any()
    assert np.all(view.depth[18:30, 33:36] == 0)
    assert landed[18:30, 36].all() and np.all(cols[18:30, 36] == 38)
    # Nothing comes into the frame from the right: the last column is a hole.
    assert not landed[:, 63].any()


def test_a_move_down_shifts_by_the_vertical_focal_length() -> None:
    # A camera with fy = 40 px moved 0.1 m down: the box (1 m) rises by 40 * 0.1 = 4 rows, to rows
    # 14-25, its columns unchanged; the wall (3 m) by 1.33 rows, so row 10 shows the wall's row 11.
    frame = scene(box_on_wall())
    frame.intrinsics = Intrinsics(F, 40.0, 31.5, 23.5, WIDTH, HEIGHT)
    view, _ = render_view(frame, Motion(np.eye(3), np.array([0.0, 0.1, 0.0])))
    cols, rows = source_of(view)
    assert np.all(view.depth[14:26, 26:38] == 1.0)
    assert np.array_equal(rows[14:26, 26:38], np.tile(np.arange(18, 30)[:, None], (1, 12)))
    assert np.array_equal(cols[14:26, 26:38], np.tile(np.arange(26, 38), (12, 1)))
    assert np.all(view.depth[10] == 3.0) and np.all(rows[10] == 11)


def test_a_turned_camera_sees_the_point_ahead_where_the_pinhole_model_says() -> None:
    # Turned right by 10 degrees, the camera sees the principal point (straight ahead, 2 m) at
    # x' = -2 sin 10°, z' = 2 cos 10°: column cx - f tan 10° = 31.5 - 8.816 = 22.68. Worked through
    # for the wall's pixels: the point from column 31 (x = -0.02 m) lands at 22.17 at depth
    # 1.9661 m, and its two-pixel splat (magnified 1.017x) covers columns 22 and 23; column 32's
    # lands at 23.20, covering 23 and 24, but farther (1.9731 m); column 30's covers 21 and 22. So
    # pixel (23, 23) shows column 31 of row 23 at 1.9661 m, the nearer of the two.
    frame = scene(wall(2.0))
    view, _ = render_view(frame, Motion(rotation_from_angles(10.0, 0.0, 0.0), np.zeros(3)))
    cols, rows = source_of(view)
    assert (cols[23, 23], rows[23, 23]) == (31, 23)
    assert view.depth[23, 23] == pytest.approx(1.96614, abs=1e-4)
    # A roll of 90 degrees: the camera's x axis is the frame's y, so the point at column 41, row 23
    # (x = 0.38 m, y = -0.02 m at 2 m) is at x' = -0.02, y' = -0.38: pixel (row 14, column 31).
    rolled, _ = render_view(frame, Motion(rotation_from_angles(0.0, 0.0, 90.0), np.zeros(3)))
    cols, rows = source_of(rolled)
    assert (cols[14, 31], rows[14, 31]) == (41, 23)
    assert rolled.depth[14, 31] == pytest.approx(2.0)


def test_motions_stay_within_their_bounds_and_scale_with_the_frame() -> None:
    settings = RenderedViews(share=0.5, forward=0.45, back=0.15, sideways=0.1, turn_deg=8, roll_deg=4)
    rng = np.random.default_rng(0)
    moves = [sample_motion(rng, 2.0, settings) for _ in range(500)]
    centres = np.array([m.centre for m in moves])
    assert centres[:, 2].max() <= 0.9 and centres[:, 2].min() >= -0.3  # 45% forward, 15% back of 2 m
    assert centres[:, 2].max() > 0.8 and centres[:, 2].min() < -0.25
    assert np.abs(centres[:, :2]).max() <= 0.2
    angles = [math.degrees(math.acos(np.clip((np.trace(m.rotation) - 1) / 2, -1, 1))) for m in moves]
    assert max(angles) <= math.sqrt(8**2 + 8**2 + 4**2) + 1e-6
    assert all(np.allclose(m.rotation @ m.rotation.T, np.eye(3)) for m in moves)


def test_the_bank_is_made_once_and_found_again(tmp_path) -> None:
    frames = [scene(box_on_wall()), scene(wall(2.0))]
    settings = RenderedViews(share=0.5, per_frame=2)
    bank = view_bank(frames, settings, 0, tmp_path)
    assert len(bank.reader) == 4 and bank.render_ms > 0
    again = view_bank(frames, settings, 0, tmp_path)
    assert math.isnan(again.render_ms)  # found made: nothing rendered
    # The views read back as rendered, depth to the millimetre, holes as no depth.
    view = bank.view(1, 1)
    rendered, _ = render_view(frames[1], sample_motion(np.random.default_rng([0, 1, 1, 3]), 2.0, settings))
    assert np.abs(view.depth - np.round(rendered.depth, 3)).max() < 1e-6
    assert np.array_equal(view.rgb, rendered.rgb)
    # Other settings render a new bank.
    assert view_bank(frames, settings.model_copy(update={"forward": 0.3}), 0, tmp_path).render_ms > 0


def test_a_view_rendered_at_a_share_of_its_frame_trains_at_the_frame_s_pixels(tmp_path):
    """A bank rendered at half the frames' size (twice the transform's largest scale, 0.25) is zoomed by twice
    as much: a still view's training sample is the frame's own, at the same size, depth and camera."""
    from contract.codec import DepthEncoding
    from trainer.config import TransformConfig
    from trainer.data.dataset import TrainingSet
    from trainer.data.views import render_scale

    frames = [scene(box_on_wall())]
    still = RenderedViews(share=1.0, per_frame=1, forward=0, back=0, sideways=0, turn_deg=0, roll_deg=0)
    transform = TransformConfig(size=(12, 16), scale=(0.25, 0.25), flip=False, brightness=0, contrast=0, saturation=0)
    assert render_scale(transform) == 0.5
    bank = view_bank(frames, still, 0, tmp_path, render_scale(transform))
    assert bank.view(0, 0).depth.shape == (24, 32) and bank.view(0, 0).intrinsics == CAMERA.resized(32, 24)
    encoding = DepthEncoding(min_m=0.25, max_m=10.0)
    with_views = TrainingSet(frames, transform, encoding, 0, 1, 4, bank, 1.0)[0, 0]
    without = TrainingSet(frames, transform, encoding, 0, 1, 4)[0, 0]
    assert with_views["metres"].shape == without["metres"].shape == (1, 12, 16)
    assert (with_views["metres"] == without["metres"]).float().mean() >= 0.9  # nearest twice, against once
