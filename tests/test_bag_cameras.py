"""A bag's cameras as fit must read them: overrides, aligned depth and rectified topics, against scenes drawn by hand.

Each bag is written with ``rosbags`` and carries lens distortion and a CameraInfo of another size than its
images (a driver reporting the sensor's full size), as real recordings do. Every scene is a board whose
edge stands ``EDGE_X`` m right of the colour camera's axis at 1 m, in front of a wall at 2 m. Where the
photo and the depth show that edge is worked out here from the cameras' numbers alone (the photo through
its lens with OpenCV's inverse model, ``undistortPoints``), so the registered depth must land on the
photo's edge, and both where the numbers put them.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from contract.errors import UserError
from contract.geometry import Intrinsics
from harness.recordings import BagWriter
from recordings.folders import CameraFile
from recordings.formats import ReadOptions, open_recording

#: The board's edge at 1 m, in the colour camera's frame: photo pixels whose ray has x / z below it see the board.
EDGE_X = 0.151
#: The depth camera sits 5 cm along the colour camera's x: colour-frame point = depth-frame point + (OFFSET, 0, 0).
OFFSET = 0.05
#: The colour photos' true camera (320x240), and a barrel lens.
COLOUR = Intrinsics(250.0, 250.0, 159.5, 119.5, 320, 240)
BARREL = (-0.25, 0.06, 0.001, -0.0005, 0.0)
#: The depth camera: rectified (no distortion), half the colour size.
DEPTH = Intrinsics(120.0, 120.0, 79.5, 59.5, 160, 120)


def normalised_x(camera: Intrinsics, coefficients: tuple[float, ...] | None) -> np.ndarray:
    """Each pixel's ray x / z through the lens: OpenCV's inverse model where there is distortion."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    if not coefficients:
        return (u - camera.cx) / camera.fx
    matrix = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]])
    pixels = np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(pixels, matrix, np.asarray(coefficients)).reshape(camera.height, camera.width, 2)
    return rays[..., 0]


def board_photo(camera: Intrinsics, coefficients: tuple[float, ...] | None = None) -> np.ndarray:
    """The scene through ``camera`` and its lens: a dark board left of the edge, a bright wall right of it."""
    on_board = normalised_x(camera, coefficients) < EDGE_X
    return np.repeat(np.where(on_board, 40, 210).astype(np.uint8)[..., None], 3, axis=2)


def board_depth(camera: Intrinsics, origin_x: float) -> np.ndarray:
    """Millimetres as a pinhole ``camera`` at ``origin_x`` on the colour camera's x axis sees the scene."""
    on_board = origin_x + normalised_x(camera, None) < EDGE_X
    return np.where(on_board, 1000, 2000).astype(np.uint16)


def hand_edge(camera: Intrinsics) -> int:
    """The first column of wall a pinhole ``camera`` (the undistorted photo's) sees in every row."""
    return int(np.floor(camera.cx + camera.fx * EDGE_X)) + 1


def edges(recording, index: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Per row: the first bright photo column and the first wall depth column of a written pair."""
    pair = recording.pairs[index]
    photo = np.asarray(Image.open(pair.rgb).convert("L"), dtype=np.float32)
    depth = np.asarray(Image.open(pair.depth), dtype=np.float32)
    # Every 10th row that shows the wall in both (a barrel lens, or a wider camera, leaves some without depth).
    rows = [r for r in range(10, photo.shape[0] - 10, 10) if (photo[r] > 125).any() and (depth[r] > 1500).any()]
    assert len(rows) >= 15, rows
    photo_edge = np.array([np.argmax(photo[r] > 125) for r in rows])
    depth_edge = np.array([np.argmax(depth[r] > 1500) for r in rows])
    return photo_edge, depth_edge


def tf_bag(path: Path, info: Intrinsics, *, distortion=BARREL, rectified: Intrinsics | None = None, raw=True) -> Path:
    """A ROS 2 bag of the scene: colour (raw through ``distortion``, and/or rectified through ``rectified``),
    depth from ``DEPTH`` joined by /tf_static, and a colour CameraInfo ``info`` (its own size and K)."""
    depth = board_depth(DEPTH, OFFSET)
    p = rectified.resized(info.width, info.height) if rectified else None
    with BagWriter(path, "ros2") as bag:
        bag.tf_static(99.0, "camera_link", "camera_color_optical_frame", (0.0, 0.0, 0.0))
        bag.tf_static(99.0, "camera_link", "camera_depth_optical_frame", (OFFSET, 0.0, 0.0))
        for i in range(2):
            t = 100.0 + i / 30
            if raw:
                bag.image(
                    "/camera/color/image_raw", t, board_photo(COLOUR, distortion), "rgb8", "camera_color_optical_frame"
                )
            if rectified is not None:
                bag.image(
                    "/camera/color/image_rect_color", t, board_photo(rectified), "rgb8", "camera_color_optical_frame"
                )
            model = ("plumb_bob", distortion)
            bag.camera_info(
                "/camera/color/camera_info", t, info, "camera_color_optical_frame", distortion=model, rectified=p
            )
            bag.image("/camera/depth/image_rect_raw", t, depth, "16UC1", "camera_depth_optical_frame")
            bag.camera_info("/camera/depth/camera_info", t, DEPTH, "camera_depth_optical_frame")
    return path


def test_the_recorded_camera_registers_depth_onto_the_undistorted_photo_edge(tmp_path):
    """No override: the 640x480 CameraInfo is scaled to the 320x240 images and its lens undone; the edges meet."""
    bag = tf_bag(tmp_path / "rec", COLOUR.resized(640, 480))
    recording = open_recording(bag, None, ReadOptions(), tmp_path / "scratch")
    assert recording.pairs[0].camera == COLOUR
    photo, depth = edges(recording)
    assert np.all(np.abs(photo - hand_edge(COLOUR)) <= 1), photo
    assert np.all(np.abs(depth - photo) <= 1), (photo, depth)


def test_overrides_are_in_the_pixels_of_the_images_and_are_never_scaled(tmp_path):
    """The bag's 640x480 CameraInfo is 20% off; --fx --fy --cx --cy give the true camera of the 320x240 images.

    The camera used must be the override itself (a reader that merges before scaling halves it), and the
    photo's lens is undone and the depth registered with it: the edges meet where the true camera puts them."""
    wrong = Intrinsics(COLOUR.fx * 1.2, COLOUR.fy * 1.2, 150.0, 110.0, 320, 240).resized(640, 480)
    bag = tf_bag(tmp_path / "rec", wrong)
    k = COLOUR
    options = ReadOptions(camera=CameraFile(fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy))
    recording = open_recording(bag, None, options, tmp_path / "scratch")
    camera = recording.pairs[0].camera
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height) == (
        250,
        250,
        159.5,
        119.5,
        320,
        240,
    )
    photo, depth = edges(recording)
    assert np.all(np.abs(photo - hand_edge(COLOUR)) <= 1), photo
    assert np.all(np.abs(depth - photo) <= 1), (photo, depth)


def test_the_issue_s_repro_an_override_on_a_larger_camera_info_is_used_as_given(tmp_path):
    """CameraInfo 1280x720, images 640x360, --fx 500 --fy 500 --cx 320 --cy 180: the camera is exactly those."""
    info = Intrinsics(900.0, 900.0, 640.0, 360.0, 1280, 720)
    rgb = np.full((360, 640, 3), 128, np.uint8)
    with BagWriter(tmp_path / "rec.bag", "ros1") as bag:
        for i in range(2):
            t = 1.0 + i / 30
            bag.image("/camera/color/image_raw", t, rgb, "rgb8")
            bag.camera_info("/camera/color/camera_info", t, info, distortion=("plumb_bob", BARREL))
            bag.image("/camera/aligned_depth_to_color/image_raw", t, np.full((360, 640), 1500, np.uint16), "16UC1")
            bag.camera_info("/camera/aligned_depth_to_color/camera_info", t, info, distortion=("plumb_bob", BARREL))
    options = ReadOptions(camera=CameraFile(fx=500, fy=500, cx=320, cy=180))
    camera = open_recording(tmp_path / "rec.bag", None, options, tmp_path / "scratch").pairs[0].camera
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height) == (500, 500, 320, 180, 640, 360)


def box_bag(
    path: Path, info: Intrinsics, distortion: tuple[float, ...], uncalibrated: bool = False, box=(20, 40, 30, 50)
) -> Path:
    """An 80x60 realsense-ros style bag, depth aligned to colour: a box at 1 m over rows ``box[0]:box[1]``,
    columns ``box[2]:box[3]`` (by default 30-49, rows 20-39), drawn at the same pixels of the photo and of the
    depth, on a wall at 2 m; its CameraInfo ``info`` is for 160x120."""
    top, bottom, left, right = box
    rgb = np.full((60, 80, 3), 210, np.uint8)
    rgb[top:bottom, left:right] = 40
    mm = np.full((60, 80), 2000, np.uint16)
    mm[top:bottom, left:right] = 1000
    model = ("plumb_bob", distortion)
    with BagWriter(path, "ros1") as bag:
        for i in range(2):
            t = 1.0 + i / 30
            bag.image("/camera/color/image_raw", t, rgb, "rgb8")
            bag.camera_info("/camera/color/camera_info", t, info, distortion=model, uncalibrated=uncalibrated)
            bag.image("/camera/aligned_depth_to_color/image_raw", t, mm, "16UC1")
            bag.camera_info(
                "/camera/aligned_depth_to_color/camera_info", t, info, distortion=model, uncalibrated=uncalibrated
            )
    return path


#: The box bag's camera at 80x60 is fx 60; its CameraInfo says so for 160x120.
BOX_INFO = Intrinsics(120.0, 120.0, 79.5, 59.5, 160, 120)


def test_an_override_on_aligned_depth_leaves_the_depth_where_it_was_recorded(tmp_path):
    """--fx 75 on an aligned bag changes the camera, not the depth: the box stays at columns 30-49."""
    bag = box_bag(tmp_path / "rec.bag", BOX_INFO, (0.0,) * 5)
    recording = open_recording(bag, None, ReadOptions(camera=CameraFile(fx=75.0)), tmp_path / "scratch")
    assert recording.pairs[0].camera == Intrinsics(75.0, 60.0, 39.5, 29.5, 80, 60)
    depth = np.asarray(Image.open(recording.pairs[0].depth))
    assert np.flatnonzero(depth[30] == 1000).tolist() == list(range(30, 50))
    assert np.flatnonzero(depth[:, 40] == 1000).tolist() == list(range(20, 40))
    assert any("aligned to colour in the bag" in note for note in recording.notes)


def test_aligned_depth_through_a_distorted_lens_is_undone_with_the_photo_and_stays_on_its_edges(tmp_path):
    """Both images of an aligned bag go through one lens. A box in the corner, where a k1 of -0.3 moves pixels
    by several, comes out of the undistortion moved (so the lens was undone), and its depth edges are the
    photo's in every row (so depth went through the same lens, not another or none)."""
    bag = box_bag(tmp_path / "rec.bag", BOX_INFO, (-0.5, 0.1, 0.0, 0.0, 0.0), box=(2, 16, 0, 11))
    recording = open_recording(bag, None, ReadOptions(camera=CameraFile(fx=75.0)), tmp_path / "scratch")
    photo = np.asarray(Image.open(recording.pairs[0].rgb).convert("L"), dtype=np.float32)
    depth = np.asarray(Image.open(recording.pairs[0].depth), dtype=np.float32)
    box_photo = photo < 125
    box_depth = (depth > 0) & (depth < 1500)
    assert box_depth.sum() > 30
    moved = 0
    for row in range(6, 14, 2):
        dark, near = np.flatnonzero(box_photo[row]), np.flatnonzero(box_depth[row])
        assert abs(dark[-1] - near[-1]) <= 1, (row, dark, near)
        moved = max(moved, abs(int(near[-1]) - 10))
    assert moved >= 2  # the box's right edge as recorded is column 10: undistorted, it is elsewhere


def test_an_uncalibrated_aligned_bag_is_read_with_all_four_overrides_and_refused_with_fewer(tmp_path):
    bag = box_bag(tmp_path / "rec.bag", BOX_INFO, (0.0,) * 5, uncalibrated=True)
    four = CameraFile(fx=60.0, fy=60.0, cx=39.5, cy=29.5)
    recording = open_recording(bag, None, ReadOptions(camera=four), tmp_path / "a")
    assert recording.pairs[0].camera == Intrinsics(60.0, 60.0, 39.5, 29.5, 80, 60)
    assert np.flatnonzero(np.asarray(Image.open(recording.pairs[0].depth))[30] == 1000).tolist() == list(range(30, 50))
    with pytest.raises(
        UserError, match=r"pass all of --fx --fy --cx --cy for the colour camera \(--cx, --cy missing\)"
    ):
        open_recording(bag, None, ReadOptions(camera=CameraFile(fx=60.0, fy=60.0)), tmp_path / "b")


def test_a_rectified_topic_is_read_at_its_projection_matrix_and_not_undistorted_again(tmp_path):
    """image_rect_color is the raw image with D undone, resampled to P: here P's focal length is 0.9 of K's and
    its principal point 10 px left. Read with P and nothing undone, its edge and the depth's meet where P puts
    them; read with K and D (the raw image's), both would land elsewhere."""
    rectified = Intrinsics(COLOUR.fx * 0.9, COLOUR.fy * 0.9, COLOUR.cx - 10, COLOUR.cy, 320, 240)
    bag = tf_bag(tmp_path / "rec", COLOUR.resized(640, 480), rectified=rectified)
    recording = open_recording(bag, None, ReadOptions(), tmp_path / "scratch")
    assert recording.notes[0].startswith("bag: colour /camera/color/image_rect_color")
    assert recording.pairs[0].camera == rectified
    assert not any("lens distortion undone" in note for note in recording.notes)
    photo, depth = edges(recording)
    assert np.all(np.abs(photo - hand_edge(rectified)) <= 1), photo
    assert np.all(np.abs(depth - photo) <= 1), (photo, depth)


def test_depth_aligned_to_the_raw_image_beside_a_rectified_topic_goes_through_the_raw_lens(tmp_path):
    """aligned_depth_to_color is in the raw colour image's pixels, distortion and all. With image_rect_color
    chosen, the depth is undone with the raw lens (K, D) and drawn in the rectified camera (P): its edge then
    meets the rectified photo's where P puts it."""
    rectified = Intrinsics(COLOUR.fx * 0.9, COLOUR.fy * 0.9, COLOUR.cx - 10, COLOUR.cy, 320, 240)
    info = COLOUR.resized(640, 480)
    raw_depth = np.where(normalised_x(COLOUR, BARREL) < EDGE_X, 1000, 2000).astype(np.uint16)
    with BagWriter(tmp_path / "rec", "ros2") as bag:
        for i in range(2):
            t = 100.0 + i / 30
            bag.image("/camera/color/image_raw", t, board_photo(COLOUR, BARREL), "rgb8")
            bag.image("/camera/color/image_rect_color", t, board_photo(rectified), "rgb8")
            bag.camera_info(
                "/camera/color/camera_info",
                t,
                info,
                distortion=("plumb_bob", BARREL),
                rectified=rectified.resized(640, 480),
            )
            bag.image("/camera/aligned_depth_to_color/image_raw", t, raw_depth, "16UC1")
            bag.camera_info("/camera/aligned_depth_to_color/camera_info", t, info, distortion=("plumb_bob", BARREL))
    recording = open_recording(tmp_path / "rec", None, ReadOptions(), tmp_path / "scratch")
    assert recording.pairs[0].camera == rectified
    assert any("aligned to the raw colour image" in note for note in recording.notes)
    photo, depth = edges(recording)
    assert np.all(np.abs(photo - hand_edge(rectified)) <= 1), photo
    assert np.all(np.abs(depth - photo) <= 1), (photo, depth)


def test_aligned_depth_of_another_size_than_the_photo_is_refused(tmp_path):
    with BagWriter(tmp_path / "rec.bag", "ros1") as bag:
        for i in range(2):
            t = 1.0 + i / 30
            bag.image("/camera/color/image_raw", t, np.zeros((60, 80, 3), np.uint8), "rgb8")
            bag.camera_info("/camera/color/camera_info", t, BOX_INFO)
            bag.image("/camera/aligned_depth_to_color/image_raw", t, np.full((30, 40), 1000, np.uint16), "16UC1")
            bag.camera_info("/camera/aligned_depth_to_color/camera_info", t, BOX_INFO)
    with pytest.raises(UserError, match=r"is said to be aligned to colour, but its images are 40x30"):
        open_recording(tmp_path / "rec.bag", None, ReadOptions(), tmp_path / "scratch")
