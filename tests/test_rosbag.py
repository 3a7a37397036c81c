"""ROS bags as fit reads them: the real RealSense Viewer recording, and bags written with rosbags' own writers.

Each written bag carries real mOSD frames (../shared/data/mosd-tabletop) in the encodings and topic
layouts robots and the RealSense ROS wrapper write, so reading it back must give those frames again.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import DATA, REPO, run_cli
from PIL import Image

from contract.card import load_card
from contract.errors import UserError
from contract.geometry import ColourCamera, Intrinsics
from harness.recordings import MOSD_CAMERA, BagWriter, write_aligned_bag
from recordings.folders import CameraFile
from recordings.formats import ReadOptions, detect_format, open_recording
from recordings.frames import Frame
from recordings.registration import alignment
from recordings.rosbag import BagOptions, read_bag

REALSENSE_BAG = DATA / "captures" / "realsense-viewer-d435.bag"
MOSD = DATA / "mosd-tabletop"


def mosd_frames(count: int, scale: float = 1.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """``count`` real mOSD (rgb uint8, depth uint16 mm) pairs, resized by ``scale``."""
    frames = []
    for colour in sorted((MOSD / "color").glob("learn*.jpg"))[:count]:
        rgb = Image.open(colour).convert("RGB")
        depth = Image.open(MOSD / "depth" / f"{colour.stem}.png")
        if scale != 1.0:
            size = (round(rgb.width * scale), round(rgb.height * scale))
            rgb, depth = rgb.resize(size, Image.BILINEAR), depth.resize(size, Image.NEAREST)
        frames.append((np.asarray(rgb), np.asarray(depth, dtype=np.uint16)))
    return frames


def test_the_realsense_viewer_bag_is_registered_into_its_colour_camera(tmp_path):
    """Depth not aligned in the bag is moved with its extrinsics, and then lines up with colour edges better."""
    bag = read_bag(REALSENSE_BAG, tmp_path, BagOptions(max_gap_s=0.15))
    assert len(bag.pairs) == 1 and bag.skipped == []
    assert (bag.pairs[0].camera.fx, bag.pairs[0].camera.width) == (pytest.approx(613.2037, abs=1e-3), 640)
    assert "mono16" in bag.notes[0] and "depth unit 1 mm" in bag.notes[0]
    assert "RealSense recording's extrinsics (translation 14.3 mm" in bag.notes[2]
    name, colour_file, depth_file = bag.pairs[0].name, bag.pairs[0].rgb, bag.pairs[0].depth
    rgb = np.asarray(Image.open(colour_file).convert("RGB"))
    registered = np.asarray(Image.open(depth_file), dtype=np.float32) / 1000.0
    assert registered.shape == (480, 640) and np.median(registered[registered > 0]) == pytest.approx(1.54, abs=0.1)
    # The raw depth frame nearest the colour frame, read as if it were in the colour camera.
    from rosbags.highlevel import AnyReader

    with AnyReader([REALSENSE_BAG]) as reader:
        connection = next(c for c in reader.connections if c.topic == "/device_0/sensor_0/Depth_0/image/data")
        raw_message = reader.deserialize(next(reader.messages(connections=[connection]))[2], connection.msgtype)
    raw = np.frombuffer(bytes(raw_message.data), np.uint16).reshape(480, 640).astype(np.float32) / 1000.0
    k = bag.pairs[0].camera
    same = ColourCamera(fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy)  # the project's edge score, depth read as it stands
    as_registered = alignment([Frame(rgb, registered, k, name)], same)
    as_recorded = alignment([Frame(rgb, raw, k, name)], same)
    print(f"\nedge score on the RealSense frame: registered {as_registered:.3f}, as recorded {as_recorded:.3f}")
    assert as_registered > as_recorded, (as_registered, as_recorded)


@pytest.mark.parametrize(
    "kind,colour,depth", [("ros1", "rgb8", "16UC1"), ("ros2", "bgr8", "32FC1"), ("mcap", "jpeg", "16UC1")]
)
def test_a_written_bag_reads_back_as_its_frames(tmp_path, kind, colour, depth):
    frames = mosd_frames(4, scale=0.5)
    path = tmp_path / ("rec.bag" if kind == "ros1" else "rec")
    write_aligned_bag(path, kind, frames, colour, depth)
    assert detect_format(path) == "rosbag"
    recording = open_recording(path, None, ReadOptions(), tmp_path / "scratch")
    assert [p.name for p in recording.pairs] == [f"{100 + i / 30:.6f}" for i in range(4)]
    assert (
        "aligned to colour in the bag" in recording.notes[2] and "/camera/aligned_depth_to_color" in recording.notes[0]
    )
    assert (recording.pairs[0].camera.fx, recording.pairs[0].depth_scale) == (262.5, 1000.0)
    for pair, (rgb, mm) in zip(recording.pairs, frames, strict=True):
        np.testing.assert_array_equal(np.asarray(Image.open(pair.depth)), mm)
        read = np.asarray(Image.open(pair.rgb).convert("RGB"), dtype=np.int16)
        assert np.abs(read - rgb).mean() < 3  # the JPEG as stored in the bag, or raw pixels written as one
    if colour == "jpeg":  # a photo recorded at the written size is kept byte for byte
        from rosbags.highlevel import AnyReader

        with AnyReader([path]) as reader:
            connection = next(c for c in reader.connections if c.topic.endswith("/compressed"))
            first = reader.deserialize(next(reader.messages(connections=[connection]))[2], connection.msgtype)
        assert recording.pairs[0].rgb.read_bytes() == bytes(first.data)


def board_and_wall(camera: Intrinsics, origin_x: float) -> np.ndarray:
    """Depth (m) seen by ``camera`` at ``origin_x`` on the colour camera's x axis, worked out by hand: a board
    at 1 m over the colour frame's x < 0, and a wall at 2 m behind everything. No function under test."""
    u = np.arange(camera.width, dtype=np.float64)
    on_board = origin_x + 1.0 * (u - camera.cx) / camera.fx < 0
    row = np.where(on_board, 1.0, 2.0).astype(np.float32)
    return np.repeat(row[None, :], camera.height, axis=0)


#: The colour camera of ``board_bag``'s photos, and its depth camera: half the size, 5 cm along x.
BOARD_COLOUR = MOSD_CAMERA.resized(320, 240)
BOARD_DEPTH = Intrinsics(120.0, 120.0, 79.5, 59.5, 160, 120)
BOARD_OFFSET = np.array([0.05, 0.0, 0.0])  # colour-frame points = depth-frame points + offset


def board_bag(root: Path, colour_info: Intrinsics) -> Path:
    """A ROS 2 bag of real photos and the analytic board-and-wall depth from ``BOARD_DEPTH``, joined to the
    colour camera by /tf_static; the colour topic's CameraInfo says ``colour_info``."""
    seen = board_and_wall(BOARD_DEPTH, BOARD_OFFSET[0])
    with BagWriter(root, "ros2") as bag:
        bag.tf_static(99.0, "camera_link", "camera_color_optical_frame", (0.0, 0.0, 0.0))
        bag.tf_static(99.0, "camera_link", "camera_depth_optical_frame", tuple(BOARD_OFFSET))
        for i, (rgb, _) in enumerate(mosd_frames(2, scale=0.5)):
            t = 100.0 + i / 30
            bag.image("/camera/color/image_raw", t, rgb, "rgb8", "camera_color_optical_frame")
            bag.camera_info("/camera/color/camera_info", t, colour_info, "camera_color_optical_frame")
            bag.image("/camera/depth/image_rect_raw", t, np.rint(seen * 1000).astype(np.uint16), "16UC1", "d")
            bag.camera_info("/camera/depth/camera_info", t, BOARD_DEPTH, "camera_depth_optical_frame")
    return root


def test_depth_in_another_camera_is_moved_through_tf_static(tmp_path):
    """Depth from a half-resolution camera 5 cm along x from the colour camera, joined by /tf_static.

    Both views are drawn analytically, so a translation read with the wrong sign (or applied with one)
    puts the board's edge 2 x fx x b / z = 26 px from where the colour camera sees it, and fails.
    """
    colour_camera = BOARD_COLOUR
    board_bag(tmp_path / "rec", colour_camera)
    recording = open_recording(tmp_path / "rec", None, ReadOptions(), tmp_path / "scratch")
    assert "with /tf_static (translation 50.0 mm" in recording.notes[2]
    truth = board_and_wall(colour_camera, 0.0)[120] * 1000
    back = np.asarray(Image.open(recording.pairs[0].depth), dtype=np.float32)[120]
    board_edge = np.flatnonzero(truth == 1000)[-1]  # the board's last column: the colour camera's cx
    assert np.flatnonzero(back == 1000)[-1] == board_edge
    seen_both = (back > 0) & (np.abs(np.arange(320) - board_edge) > 14)  # away from the hidden strip
    np.testing.assert_array_equal(back[seen_both], truth[seen_both])


def test_bags_that_cannot_be_fitted_are_refused_in_one_line(tmp_path):
    frames = mosd_frames(2, scale=0.25)
    with BagWriter(tmp_path / "colour-only.bag", "ros1") as bag:
        bag.image("/camera/color/image_raw", 1.0, frames[0][0], "rgb8")
        bag.camera_info("/camera/color/camera_info", 1.0, MOSD_CAMERA.resized(160, 120))
    with pytest.raises(UserError, match=r"colour-only.bag: no depth image topic \(image topics: /camera/color"):
        read_bag(tmp_path / "colour-only.bag", tmp_path / "a")
    with BagWriter(tmp_path / "no-info.bag", "ros1") as bag:
        bag.image("/camera/color/image_raw", 1.0, frames[0][0], "rgb8")
        bag.image("/camera/depth/image_raw", 1.0, frames[0][1], "16UC1")
    with pytest.raises(UserError, match=r"no-info.bag: no CameraInfo for /camera/color/image_raw"):
        read_bag(tmp_path / "no-info.bag", tmp_path / "b")
    apart = tmp_path / "apart"
    with BagWriter(apart, "ros2") as bag:
        for i, (rgb, mm) in enumerate(frames):
            bag.image("/cam/color/image_raw", 10.0 + i, rgb, "rgb8")
            bag.camera_info("/cam/color/camera_info", 10.0 + i, MOSD_CAMERA.resized(160, 120))
            bag.image("/cam/aligned_depth_to_color/image_raw", 10.5 + i, mm, "16UC1")
            bag.camera_info("/cam/aligned_depth_to_color/camera_info", 10.5 + i, MOSD_CAMERA.resized(160, 120))
    with pytest.raises(UserError, match=r"no colour frame of /cam/color/image_raw has depth .* within 20 ms"):
        read_bag(apart, tmp_path / "c")
    assert len(read_bag(apart, tmp_path / "d", BagOptions(max_gap_s=0.6)).pairs) == 2
    (tmp_path / "broken.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 64)
    with pytest.raises(UserError, match=r"broken.bag: not a readable ROS bag"):
        read_bag(tmp_path / "broken.bag", tmp_path / "e")


@pytest.mark.slow
def test_fit_from_a_ros2_bag_publishes_a_model(registry, tmp_path):
    bag = write_aligned_bag(tmp_path / "rec", "ros2", mosd_frames(24, scale=0.25))
    args = ["fit", str(bag), "--name", "bag-room", "--licence", "mOSD (research use), test copy", "--budget", "1"]
    args += ["--from", str(registry / "tiny" / "0.1.0"), "--registry", str(tmp_path / "registry")]
    out = run_cli(*args, "--out", str(tmp_path / "run"), "--register", "no", "--every", "1", cwd=REPO).stdout
    assert "(rosbag)" in out and "paired within 20 ms: 24 of 24 colour frames" in out
    assert "pairs: 24 found, 0 skipped" in out and "| fitted model |" in out
    card = load_card(tmp_path / "registry" / "bag-room" / "0.1.0")
    assert card.training.data[0].format == "rosbag"


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_compressed_depth_is_decoded_from_its_header(tmp_path, encoding):
    """image_transport's compressedDepth: 16UC1 holds millimetres, 32FC1 quantised inverse depth (v = A / d + B)."""
    frames = mosd_frames(2, scale=0.25)
    k = MOSD_CAMERA.resized(160, 120)
    with BagWriter(tmp_path / "rec.bag", "ros1") as bag:
        for i, (rgb, mm) in enumerate(frames):
            t = 1.0 + i / 30
            bag.image("/camera/color/image_raw", t, rgb, "rgb8")
            bag.camera_info("/camera/color/camera_info", t, k)
            bag.compressed_depth("/camera/aligned_depth_to_color/image_raw/compressedDepth", t, mm / 1000.0, encoding)
            bag.camera_info("/camera/aligned_depth_to_color/camera_info", t, k)
    recording = open_recording(tmp_path / "rec.bag", None, ReadOptions(), tmp_path / "scratch")
    assert f"({encoding}; compressedDepth png" in recording.notes[0]
    truth = frames[1][1].astype(np.float64)
    back = np.asarray(Image.open(recording.pairs[1].depth), dtype=np.float64)
    np.testing.assert_array_equal(back > 0, truth > 0)
    valid = truth > 0
    # 32FC1's steps at depth d are d^2 / A wide: 0.4 mm at 2 m with the plugin's defaults (A = 10100).
    tolerance = 0.5 if encoding == "16UC1" else (truth[valid] / 1000) ** 2 / 10100 * 1000 + 0.5
    assert np.all(np.abs(back[valid] - truth[valid]) <= tolerance)


def distorted_edge(camera: Intrinsics, coefficients: np.ndarray, edge_x: float) -> np.ndarray:
    """A photo through a lens with ``coefficients`` (plumb_bob) of a scene whose undistorted image is dark left of
    column ``edge_x`` and bright right of it: each distorted pixel's undistorted position from OpenCV's
    ``undistortPoints`` (the inverse model, not the remap the reader uses)."""
    import cv2

    matrix = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]])
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    undistorted = cv2.undistortPoints(pixels, matrix, coefficients, P=matrix).reshape(camera.height, camera.width, 2)
    bright = undistorted[..., 0] > edge_x
    return np.repeat(np.where(bright, 220, 30).astype(np.uint8)[..., None], 3, axis=2)


def test_lens_distortion_in_camera_info_is_undone_before_anything_is_written(tmp_path):
    """A straight edge photographed through barrel distortion (k1 -0.3) is bent; read back, it is straight."""
    camera = Intrinsics(200.0, 200.0, 159.5, 119.5, 320, 240)
    coefficients = np.array([-0.3, 0.08, 0.0, 0.0, 0.0])
    photo = distorted_edge(camera, coefficients, edge_x=279.5)
    depth = np.full((240, 320), 1500, np.uint16)
    with BagWriter(tmp_path / "rec.bag", "ros1") as bag:
        for i in range(2):
            t = 1.0 + i / 30
            bag.image("/camera/color/image_raw", t, photo, "rgb8")
            bag.camera_info("/camera/color/camera_info", t, camera, distortion=("plumb_bob", tuple(coefficients)))
            bag.image("/camera/aligned_depth_to_color/image_raw", t, depth, "16UC1")
            bag.camera_info("/camera/aligned_depth_to_color/camera_info", t, camera)
    recording = open_recording(tmp_path / "rec.bag", None, ReadOptions(), tmp_path / "scratch")
    assert any("plumb_bob lens distortion undone" in note for note in recording.notes)
    bent = [int(np.argmax(photo[row, :, 0] > 125)) for row in (20, 120, 220)]
    assert bent[0] < bent[1] - 3  # as recorded the edge bows: its ends are pulled towards the centre
    back = np.asarray(Image.open(recording.pairs[0].rgb))
    straight = [int(np.argmax(back[row, :, 0] > 125)) for row in (20, 120, 220)]
    assert max(straight) - min(straight) <= 1 and abs(straight[1] - 280) <= 1


def test_a_camera_info_for_the_full_sensor_is_scaled_to_its_images(tmp_path):
    # CameraInfo for 640x480, images 160x120.
    bag = write_aligned_bag(tmp_path / "rec.bag", "ros1", mosd_frames(2, scale=0.25), info=MOSD_CAMERA)
    recording = open_recording(bag, None, ReadOptions(), tmp_path / "scratch")
    assert recording.pairs[0].camera == MOSD_CAMERA.resized(160, 120)
    assert any("640x480 camera scaled to /camera/color/image_raw's 160x120" in note for note in recording.notes)


def test_camera_overrides_reach_a_bag_before_its_depth_is_registered(tmp_path):
    """The bag's colour CameraInfo is 20% off; --fx --fy --cx --cy give the true camera. Registration must use
    the true one: the board's edge then lands where the true colour camera sees it (a bag read with the wrong
    camera and corrected afterwards puts it elsewhere)."""
    colour_camera = BOARD_COLOUR
    wrong = Intrinsics(colour_camera.fx * 1.2, colour_camera.fy * 1.2, 150.0, 110.0, 320, 240)
    board_bag(tmp_path / "rec", wrong)
    k = colour_camera
    override = CameraFile(fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy)
    recording = open_recording(tmp_path / "rec", None, ReadOptions(camera=override), tmp_path / "scratch")
    assert recording.pairs[0].camera == colour_camera
    back = np.asarray(Image.open(recording.pairs[0].depth), dtype=np.float32)[120]
    assert np.flatnonzero(back == 1000)[-1] == np.flatnonzero(board_and_wall(colour_camera, 0.0)[120] == 1)[-1]


def test_a_depth_scale_reaches_a_bag_before_its_frames_are_written(tmp_path):
    """16UC1 recorded in tenths of a millimetre: --depth-scale 10000 says so, and the written depth is right."""
    frames = mosd_frames(2, scale=0.25)
    tenths = [(rgb, (mm.astype(np.uint32) * 10).clip(0, 65535).astype(np.uint16)) for rgb, mm in frames]
    bag = write_aligned_bag(tmp_path / "rec.bag", "ros1", tenths)
    options = ReadOptions(camera=CameraFile(depth_scale=10000.0))
    recording = open_recording(bag, None, options, tmp_path / "scratch")
    back = np.asarray(Image.open(recording.pairs[0].depth), dtype=np.int64)
    truth = frames[0][1].astype(np.int64)
    fits = truth * 10 <= 65535
    assert "depth unit 0.1 mm" in recording.notes[0]
    assert np.abs(back[fits] - truth[fits]).max() <= 1


def test_a_rectified_colour_topic_is_read_before_the_raw_one(tmp_path):
    """A bag with both the raw and the rectified colour stream: the rectified one's distortion is already undone."""
    frames = mosd_frames(2, scale=0.25)
    k = MOSD_CAMERA.resized(160, 120)
    with BagWriter(tmp_path / "rec.bag", "ros1") as bag:
        for i, (rgb, mm) in enumerate(frames):
            t = 1.0 + i / 30
            bag.image("/camera/color/image_raw", t, rgb[::-1].copy(), "rgb8")  # upside down: must not be read
            bag.image("/camera/color/image_rect_color", t, rgb, "rgb8")
            bag.camera_info("/camera/color/camera_info", t, k)
            bag.image("/camera/aligned_depth_to_color/image_raw", t, mm, "16UC1")
            bag.camera_info("/camera/aligned_depth_to_color/camera_info", t, k)
    recording = open_recording(tmp_path / "rec.bag", None, ReadOptions(), tmp_path / "scratch")
    assert recording.notes[0].startswith("bag: colour /camera/color/image_rect_color (rgb8")
    read = np.asarray(Image.open(recording.pairs[0].rgb), dtype=np.int16)
    assert np.abs(read - frames[0][0]).mean() < 3 and np.abs(read - frames[0][0][::-1]).mean() > 10
