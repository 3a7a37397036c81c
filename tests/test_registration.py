"""Registering a depth camera to the colour camera beside it, against geometry worked out by hand."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest
import yaml
from conftest import SEVEN_SCENES, run_cli

from contract.geometry import ColourCamera, Intrinsics
from recordings.frames import Frame
from recordings.registration import (
    alignment,
    colour_coordinates,
    colour_extrinsics,
    depth_to_colour,
    fit_colour_camera,
    nearest_surface,
    register_frame,
    reproject_depth,
)
from trainer.config import DataSource
from trainer.data.sources import open_source
from trainer.evaluate import evaluate_frames

DEPTH_CAMERA = Intrinsics(fx=100.0, fy=100.0, cx=39.5, cy=29.5, width=80, height=60)


def _same_camera(**changes: float) -> ColourCamera:
    return ColourCamera(fx=100.0, fy=100.0, cx=39.5, cy=29.5).model_copy(update=changes)


def _box_scene() -> np.ndarray:
    """A wall at 2 m with a box at 1 m in front of it, and a strip of missing depth."""
    depth = np.full((60, 80), 2.0, dtype=np.float32)
    depth[20:40, 30:50] = 1.0
    depth[:, :3] = 0.0
    return depth


def test_a_baseline_shifts_each_point_by_focal_times_baseline_over_depth():
    # 4 cm to the side at fx 100 px: a point at 2 m moves 2 px, one at 1 m moves 4 px.
    colour = _same_camera(baseline_m=0.04)
    xc, yc, z = colour_coordinates(_box_scene(), DEPTH_CAMERA, colour)
    assert xc[10, 10] == pytest.approx(8.0) and yc[10, 10] == pytest.approx(10.0)
    assert xc[30, 40] == pytest.approx(36.0) and z[30, 40] == pytest.approx(1.0)
    assert np.isnan(xc[5, 1])  # no depth, no place in the colour image


def test_a_wider_colour_lens_draws_the_scene_smaller_about_its_centre():
    colour = _same_camera(fx=50.0, fy=50.0)
    xc, yc, _ = colour_coordinates(_box_scene(), DEPTH_CAMERA, colour)
    assert xc[29, 79] == pytest.approx(39.5 + 0.5 * 39.5)
    assert yc[59, 40] == pytest.approx(29.5 + 0.5 * 29.5)


def test_a_roll_turns_the_image_about_the_principal_point():
    # A quarter turn (x towards y) moves a point 19.5 px right of and 0.5 px above the centre
    # to 19.5 px below and 0.5 px right of it.
    xc, yc, _ = colour_coordinates(_box_scene(), DEPTH_CAMERA, _same_camera(roll_deg=90.0))
    assert xc[29, 59] == pytest.approx(39.5 + 0.5) and yc[29, 59] == pytest.approx(29.5 + 19.5)
    # Half a degree, the size Kinect v1 shows, moves a point 300 px from the centre by 2.6 px.
    wide = Intrinsics(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
    depth = np.full((480, 640), 2.0, dtype=np.float32)
    colour = ColourCamera(fx=500.0, fy=500.0, cx=320.0, cy=240.0, roll_deg=0.5)
    xc, yc, _ = colour_coordinates(depth, wide, colour)
    assert yc[240, 620] - 240.0 == pytest.approx(300 * np.sin(np.radians(0.5)))
    assert xc[240, 620] == pytest.approx(320.0 + 300 * np.cos(np.radians(0.5)))


def test_registered_depth_moves_the_box_and_the_nearer_surface_wins():
    colour = _same_camera(baseline_m=0.04)
    registered = depth_to_colour(_box_scene(), DEPTH_CAMERA, colour)
    # The box (1 m) moves 4 px left, the wall (2 m) 2 px: the box now covers columns 26-45.
    assert np.all(registered[25:35, 26:46] == 1.0)
    assert np.all(registered[25:35, 48:78] == 2.0)
    # Where the box moved off (2 px: 4 - 2), the wall it hid from the depth camera has no reading.
    assert np.all(registered[25:35, 46:48] == 0.0)
    # The colour camera's view beyond what the depth camera covers stays empty; no hole is invented.
    assert np.all(registered[:, 78:] == 0.0)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_plane_seen_from_a_baseline_shifts_by_focal_times_baseline_over_depth(sign):
    """p_colour = p_depth + t: with t = (b, 0, 0) a point's column grows by fx * b / z; with -b it shrinks."""
    depth = np.zeros((60, 80), dtype=np.float32)
    depth[:, 20:60] = 2.5  # a plane at 2.5 m whose left and right edges are at columns 20 and 59
    b = sign * 0.1  # 10 cm at fx 100 px and 2.5 m: 4 px
    moved = reproject_depth(depth, DEPTH_CAMERA, DEPTH_CAMERA, np.eye(3), np.array([b, 0.0, 0.0]))
    columns = np.flatnonzero(moved[30] > 0)
    shift = round(100.0 * b / 2.5)
    assert (columns[0], columns[-1]) == (20 + shift, 59 + shift)
    assert np.all(moved[30, columns] == pytest.approx(2.5))


@pytest.mark.parametrize(("b", "near", "far"), [(0.1, 10, 15), (-0.1, 30, 25)])
def test_the_nearer_surface_wins_a_pixel_two_land_on_whatever_their_order(b, near, far):
    """At fx 100 px, a point at 1 m moves 100 b px and one at 2 m 50 b px: both land on column 20, the near
    one first in memory (b > 0) or last (b < 0)."""
    depth = np.zeros((60, 80), dtype=np.float32)
    depth[30, near], depth[30, far] = 1.0, 2.0
    moved = reproject_depth(depth, DEPTH_CAMERA, DEPTH_CAMERA, np.eye(3), np.array([b, 0.0, 0.0]))
    assert moved[30, 20] == 1.0 and np.count_nonzero(moved) == 1


def test_the_nearest_surface_buffer_does_not_depend_on_the_order_of_its_points():
    rng = np.random.default_rng(0)
    flat = rng.integers(0, 12, 500)
    z = rng.uniform(0.5, 5.0, 500).astype(np.float32)
    expected = np.zeros(12, dtype=np.float32)
    for index in range(12):
        expected[index] = z[flat == index].min() if np.any(flat == index) else 0.0
    for order in (np.arange(500), np.argsort(z), np.argsort(-z), rng.permutation(500)):
        np.testing.assert_array_equal(nearest_surface(flat[order], z[order], 3, 4).ravel(), expected)


def test_a_colour_camera_registers_through_the_one_reprojection():
    colour = _same_camera(fx=90.0, fy=90.0, baseline_m=0.04, roll_deg=1.5)
    rotation, translation = colour_extrinsics(colour)
    np.testing.assert_array_equal(
        depth_to_colour(_box_scene(), DEPTH_CAMERA, colour),
        reproject_depth(_box_scene(), DEPTH_CAMERA, colour.intrinsics(80, 60), rotation, translation),
    )
    # And it agrees with the per-pixel model that reads predictions back at the colour camera.
    xc, yc, z = colour_coordinates(_box_scene(), DEPTH_CAMERA, colour)
    registered = depth_to_colour(_box_scene(), DEPTH_CAMERA, colour)
    assert registered[int(np.rint(yc[30, 40])), int(np.rint(xc[30, 40]))] == pytest.approx(z[30, 40])


def test_registered_frame_carries_the_colour_camera():
    frame = Frame(np.zeros((60, 80, 3), np.uint8), _box_scene(), DEPTH_CAMERA, "box")
    colour = _same_camera(fx=90.0, fy=90.0, baseline_m=0.01)
    registered = register_frame(frame, colour)
    assert registered.intrinsics == Intrinsics(90.0, 90.0, 39.5, 29.5, 80, 60)
    assert registered.rgb is frame.rgb and registered.depth.shape == frame.depth.shape


def test_evaluation_reads_a_colour_frame_prediction_at_each_ground_truth_pixel():
    """A perfect colour-frame prediction scores perfectly only when read through the colour camera."""
    colour = _same_camera(baseline_m=0.04)
    depth = _box_scene()
    perfect_in_colour = depth_to_colour(depth, DEPTH_CAMERA, colour)
    perfect_in_colour[perfect_in_colour == 0] = 2.0  # a prediction has a value everywhere
    frames = [Frame(np.zeros((60, 80, 3), np.uint8), depth, DEPTH_CAMERA, "box")]
    args = {"min_m": 0.1, "max_m": 10.0}
    read_through, _, _ = evaluate_frames(lambda rgb, k: perfect_in_colour, frames, colour_camera=colour, **args)
    pixel_to_pixel, _, _ = evaluate_frames(lambda rgb, k: perfect_in_colour, frames, **args)
    scored = int((depth > 0).sum())
    assert read_through["pixels"] == pixel_to_pixel["pixels"] == scored
    # Every pixel reads its own depth back but two columns of wall beside the box (20 rows): the
    # depth camera sees them, while the photo sees the box in front of them. They count as misses.
    assert read_through["delta1"] == pytest.approx(1 - 40 / scored)
    # Pixel to pixel, the box and the wall are each misplaced by their shift: more misses.
    assert pixel_to_pixel["delta1"] < read_through["delta1"] - 0.01


def test_a_photo_read_through_the_colour_camera_is_predicted_as_the_colour_camera_took_it():
    """The photo of a raw Kinect pair is the colour camera's, not the depth camera's whose intrinsics the frame
    carries: the predictor (which resamples to its model's camera) must be told the colour camera."""
    colour = _same_camera(fx=90.0, fy=90.0, baseline_m=0.04)
    frames = [Frame(np.zeros((60, 80, 3), np.uint8), _box_scene(), DEPTH_CAMERA, "box")]
    seen = []

    def predict(rgb: np.ndarray, camera: Intrinsics) -> np.ndarray:
        seen.append(camera)
        return np.full(rgb.shape[:2], 1.5, np.float32)

    evaluate_frames(predict, frames, min_m=0.1, max_m=10.0, colour_camera=colour)
    evaluate_frames(predict, frames, min_m=0.1, max_m=10.0)
    assert seen == [colour.intrinsics(80, 60), DEPTH_CAMERA]


def test_the_fit_finds_a_colour_camera_from_edges_and_depth_steps():
    """Colour edges drawn by a known camera pair lead the fit from 'one camera' to that pair."""
    truth = _same_camera(fx=92.0, fy=92.0, cx=36.0, baseline_m=0.02, roll_deg=2.0)
    rng = np.random.default_rng(0)
    frames = []
    for _ in range(3):
        depth = np.full((60, 80), 3.0, dtype=np.float32)
        for _ in range(4):
            top, left = rng.integers(5, 40), rng.integers(5, 60)
            depth[top : top + 15, left : left + 15] = rng.uniform(0.8, 2.0)
        # The photo shows each surface as a flat shade, where the colour camera sees it.
        seen = depth_to_colour(depth, DEPTH_CAMERA, truth)
        grey = np.where(seen > 0, 40.0 * seen, 120.0)
        frames.append(Frame(np.repeat(grey[..., None], 3, axis=2).astype(np.uint8), depth, DEPTH_CAMERA, "s"))
    start = _same_camera()
    fitted, score = fit_colour_camera(frames, start)
    assert score > alignment(frames, start)
    assert fitted.fy == fitted.fx
    assert fitted.roll_deg == pytest.approx(truth.roll_deg, abs=0.5)

    # The principal point and the baseline trade off against each other; what matters is where
    # the pair puts each depth pixel in the photo. The fit misses the true place by about a pixel
    # of this 80x60 image, where treating the two as one camera misses it by several.
    def misplacement(camera: ColourCamera) -> float:
        true_x, true_y, _ = colour_coordinates(frames[0].depth, DEPTH_CAMERA, truth)
        x, y, _ = colour_coordinates(frames[0].depth, DEPTH_CAMERA, camera)
        return float(np.nanmean(np.hypot(x - true_x, y - true_y)))

    assert misplacement(fitted) < 1.5 and misplacement(start) > 3 * misplacement(fitted)


def test_a_source_with_a_colour_camera_trains_on_registered_depth():
    colour = ColourCamera(fx=530.0, fy=530.0, cx=314.5, cy=239.0, baseline_m=0.009)
    raw = open_source(DataSource(format="7scenes", root=SEVEN_SCENES, frames="0"))[0]
    registered = open_source(DataSource(format="7scenes", root=SEVEN_SCENES, frames="0", colour_camera=colour))[0]
    assert registered.intrinsics.fx == 530.0 and raw.intrinsics.fx == 585.0
    assert np.array_equal(registered.rgb, raw.rgb)
    # The colour camera sees wider, so its border has no depth, and the depth it has is the same scene's.
    assert 0.6 < (registered.depth > 0).mean() < (raw.depth > 0).mean()
    assert np.all(registered.depth[:, :5] == 0)
    median = np.median(registered.depth[registered.depth > 0])
    assert median == pytest.approx(np.median(raw.depth[raw.depth > 0]), rel=0.05)


def test_colour_camera_resizes_with_its_images():
    colour = ColourCamera(fx=530.0, fy=530.0, cx=314.5, cy=239.0, baseline_m=0.009)
    half = colour.resized(0.5)
    expected = colour.intrinsics(640, 480).resized(320, 240)
    assert (half.fx, half.fy, half.cx, half.cy) == (expected.fx, expected.fy, expected.cx, expected.cy)
    assert half.baseline_m == colour.baseline_m and colour.resized(1.0) is colour


@pytest.mark.slow
def test_calibrate_fits_the_real_kinect_pair_better_than_one_camera():
    same = "{fx: 585, fy: 585, cx: 320, cy: 240}"  # camera-intrinsics.txt: the depth camera's own
    args = ("calibrate", str(SEVEN_SCENES), "--frames", "0-799", "--every", "400", "--compare", same)
    stdout = run_cli(*args).stdout
    recorded = float(re.search(r"as recorded \(same camera\): ([\d.]+)", stdout).group(1))
    fitted = float(re.search(r"alignment fitted: ([\d.]+)", stdout).group(1))
    assert fitted > recorded
    # --compare scores a given camera on the same frames: the depth camera itself scores as recorded.
    compared = float(re.search(r"alignment of \{fx: 585[^}]*\}: ([\d.]+)", stdout).group(1))
    assert compared == recorded
    camera = ColourCamera.model_validate(yaml.safe_load(stdout.strip().splitlines()[-1])["colour_camera"])
    # Kinect v1's colour lens sees wider than its depth lens: a shorter focal length than 585 px.
    assert 500 < camera.fx < 570
    assert abs(camera.roll_deg) < 2.0  # two lenses on one bar: a fraction of a degree, not a tilted image


def test_evaluate_refuses_a_malformed_colour_camera(tmp_path):
    args = ["evaluate", str(tmp_path), "--format", "7scenes", "--root", str(SEVEN_SCENES), "--frames", "850"]
    result = subprocess.run(
        [sys.executable, "-m", "cli", *args, "--colour-camera", "{fx: 530}"], capture_output=True, text=True
    )
    assert result.returncode == 2
    assert "--colour-camera" in result.stderr and "fy" in result.stderr


# --- each turn and shift worked by hand: a sign flipped anywhere moves a point to the other side --------------


def _one_point(u: int, v: int, z: float) -> np.ndarray:
    depth = np.zeros((60, 80), dtype=np.float32)
    depth[v, u] = z
    return depth


def _landed(moved: np.ndarray) -> tuple[int, int]:
    (row,), (col,) = np.nonzero(moved)
    return int(col), int(row)


@pytest.mark.parametrize(("roll", "expected"), [(90.0, (40, 49)), (-90.0, (39, 10))])
def test_registration_turns_a_point_by_the_roll_s_sign(roll, expected):
    """Pixel (59, 29) is 19.5 px right of and 0.5 px above the centre (39.5, 29.5). A quarter roll (+: x towards
    y, as ``colour_coordinates`` turns it) puts it 19.5 px below and 0.5 px right; the opposite roll 19.5 px
    above and 0.5 px left."""
    moved = depth_to_colour(_one_point(59, 29, 2.0), DEPTH_CAMERA, _same_camera(roll_deg=roll))
    assert _landed(moved) == expected


@pytest.mark.parametrize(("b", "columns"), [(0.04, (26, 45)), (-0.04, (34, 53))])
def test_registration_shifts_the_box_by_the_baseline_s_sign(b, columns):
    """The colour camera b along the depth camera's x sees a point at 1 m shifted by -100 b / 1 px: 4 px left
    for 4 cm, 4 px right for -4 cm."""
    registered = depth_to_colour(_box_scene(), DEPTH_CAMERA, _same_camera(baseline_m=b))
    box = np.flatnonzero(registered[30] == 1.0)
    assert (box[0], box[-1]) == columns


#: tan(angle) = 0.1: a turn that moves the optical axis 10 px at fx 100.
TURN = float(np.degrees(np.arctan(0.1)))


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_yaw_moves_a_point_along_x_by_its_sign(sign):
    """p_colour = R p_depth with R a turn about y by +-TURN, written out here: [[c, 0, s], [0, 1, 0], [-s, 0, c]].
    A point on pixel (42, 31) at 2 m is (0.05, 0.03, 2) m; turned, it is (0.05c + 2s, 0.03, -0.05s + 2c)."""
    t = np.radians(sign * TURN)
    c, s = np.cos(t), np.sin(t)
    rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    moved = reproject_depth(_one_point(42, 31, 2.0), DEPTH_CAMERA, DEPTH_CAMERA, rotation, np.zeros(3))
    x, y, z = 0.05 * c + 2 * s, 0.03, -0.05 * s + 2 * c
    assert _landed(moved) == (round(39.5 + 100 * x / z), round(29.5 + 100 * y / z))
    assert _landed(moved) == ((52, 31) if sign > 0 else (32, 31))  # and the same worked to the pixel
    assert moved[moved > 0][0] == pytest.approx(z, rel=1e-6)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_pitch_moves_a_point_along_y_by_its_sign(sign):
    """R a turn about x by +-TURN: [[1, 0, 0], [0, c, -s], [0, s, c]]; (0.05, 0.03, 2) m goes to
    (0.05, 0.03c - 2s, 0.03s + 2c)."""
    t = np.radians(sign * TURN)
    c, s = np.cos(t), np.sin(t)
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    moved = reproject_depth(_one_point(42, 31, 2.0), DEPTH_CAMERA, DEPTH_CAMERA, rotation, np.zeros(3))
    assert _landed(moved) == ((42, 21) if sign > 0 else (42, 41))
