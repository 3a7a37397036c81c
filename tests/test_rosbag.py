"""ROS bags as fit reads them: the real RealSense Viewer recording, and bags written with rosbags' own writers.

Each written bag carries real mOSD frames (../shared/data/mosd-tabletop) in the encodings and topic
layouts robots and the RealSense ROS wrapper write, so reading it back must give those frames again.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import DATA, REPO, run_cli
from PIL import Image

from contract.card import load_card
from contract.errors import UserError
from contract.geometry import ColourCamera, Intrinsics
from harness.recordings import MOSD_CAMERA, BagWriter, write_aligned_bag
from trainer.data.formats import ReadOptions, detect_format, open_recording
from trainer.data.frames import Frame
from trainer.data.rosbag import read_bag
from trainer.registration import alignment, reproject_depth

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
    bag = read_bag(REALSENSE_BAG, tmp_path, max_gap_s=0.15)
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
        if colour == "jpeg":
            assert np.abs(read - rgb).mean() < 3  # the JPEG as stored in the bag
        else:
            np.testing.assert_array_equal(read, rgb)


def test_depth_in_another_camera_is_moved_through_tf_static(tmp_path):
    """Depth from a half-resolution camera 5 cm to the colour camera's left, joined by /tf_static."""
    frames = mosd_frames(2, scale=0.5)
    colour_camera = MOSD_CAMERA.resized(320, 240)
    depth_camera = Intrinsics(120.0, 120.0, 79.5, 59.5, 160, 120)
    offset = np.array([0.05, 0.0, 0.0])  # colour-frame points = depth-frame points + offset
    with BagWriter(tmp_path / "rec", "ros2") as bag:
        bag.tf_static(99.0, "camera_link", "camera_color_optical_frame", (0.0, 0.0, 0.0))
        bag.tf_static(99.0, "camera_link", "camera_depth_optical_frame", tuple(offset))
        for i, (rgb, mm) in enumerate(frames):
            t = 100.0 + i / 30
            bag.image("/camera/color/image_raw", t, rgb, "rgb8", "camera_color_optical_frame")
            bag.camera_info("/camera/color/camera_info", t, colour_camera, "camera_color_optical_frame")
            seen = reproject_depth(mm / 1000.0, colour_camera, depth_camera, np.eye(3), -offset)
            bag.image("/camera/depth/image_rect_raw", t, np.rint(seen * 1000).astype(np.uint16), "16UC1", "d")
            bag.camera_info("/camera/depth/camera_info", t, depth_camera, "camera_depth_optical_frame")
    recording = open_recording(tmp_path / "rec", None, ReadOptions(), tmp_path / "scratch")
    assert "with /tf_static (translation 50.0 mm" in recording.notes[2]
    truth = frames[0][1].astype(np.float32)
    back = np.asarray(Image.open(recording.pairs[0].depth), dtype=np.float32)
    both = (truth > 0) & (back > 0)
    assert both.mean() > 0.4 and np.median(np.abs(back[both] - truth[both])) < 15  # mm, after two resamplings


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
    assert len(read_bag(apart, tmp_path / "d", max_gap_s=0.6).pairs) == 2
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
