"""``rgb2cloud stream`` against the real service under uvicorn: a video, a ROS 2 bag and a folder in,
a folder of PNG/PLY files and a ROS 2 bag out, read back with Pillow, plyfile and ``rosbags``.

Expected values come from outside the command: stamps from the input read with PyAV and rosbags,
depth from ``POST /depth`` of the same photo, points from ``POST /pointcloud``.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import av
import httpx
import numpy as np
import pytest
from conftest import REPO, SEVEN_SCENES, png_header
from PIL import ExifTags, Image
from plyfile import PlyData
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from clients.stream import answers, open_stream
from harness.recordings import MOSD_CAMERA, write_aligned_bag
from harness.service import BUNDLED_REGISTRY, running_service

pytestmark = pytest.mark.slow

MOSD = REPO.parent / "shared" / "data" / "mosd-tabletop"
KITCHEN = [SEVEN_SCENES / f"frame-{n:06d}.color.jpg" for n in range(850, 910)]


@pytest.fixture(scope="module")
def service():
    with running_service(bundled_registry=BUNDLED_REGISTRY, model="rgb2cloud-7scenes", engine="onnxruntime") as up:
        yield up.url


def stream_cli(url: str, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    result = subprocess.run(
        [sys.executable, "-m", "cli", "stream", *args, "--url", url], cwd=REPO, capture_output=True, text=True
    )
    assert not check or result.returncode == 0, result.stderr
    return result


def posted_depth(url: str, photo: bytes, **params) -> np.ndarray:
    response = httpx.post(f"{url}/depth", files={"image": ("p", photo)}, params=params, timeout=60)
    response.raise_for_status()
    return np.asarray(Image.open(io.BytesIO(response.content)), dtype=np.float64) / 1000


def read_bag(path: Path) -> dict[str, list[tuple[str, int, object]]]:
    """Every message of the bag by topic: (type, bag time, message), read with rosbags alone."""
    topics: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for connection, t, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)
            topics.setdefault(connection.topic, []).append((connection.msgtype, t, message))
    return topics


def stamp_ns(message) -> int:
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


def write_video(path: Path, photos: list[Path]) -> list[int]:
    """An MPEG-4 video of the photos at 30 fps; the stamps (ns) PyAV reads back from it."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=30)
        stream.width, stream.height, stream.pix_fmt = 640, 480, "yuv420p"
        for photo in photos:
            frame = av.VideoFrame.from_image(Image.open(photo).convert("RGB"))
            container.mux(stream.encode(frame))
        container.mux(stream.encode())
    with av.open(str(path)) as container:
        return [round(float(f.pts * f.time_base) * 1e9) for f in container.decode(video=0)]


def test_a_60_frame_video_becomes_a_bag_of_depth_camera_info_and_clouds(service, tmp_path):
    stamps = write_video(tmp_path / "kitchen.mp4", KITCHEN)
    assert len(stamps) == 60
    stream_cli(service, str(tmp_path / "kitchen.mp4"), "--bag", str(tmp_path / "bag"), "--stride", "4")
    topics = read_bag(tmp_path / "bag")
    depth = topics["/rgb2cloud/aligned_depth_to_color/image_raw"]
    info = topics["/rgb2cloud/aligned_depth_to_color/camera_info"]
    clouds = topics["/rgb2cloud/depth/color/points"]
    assert [stamp_ns(m) for _, _, m in depth] == stamps == [stamp_ns(m) for _, _, m in clouds]
    assert [t for _, t, _ in depth] == stamps  # the bag's own times too
    for _, _, image in depth[:3]:
        assert image.encoding == "32FC1" and (image.width, image.height, image.step) == (640, 480, 2560)
        assert image.header.frame_id == "camera_color_optical_frame"
    msgtype, _, camera = info[0]
    assert msgtype == "sensor_msgs/msg/CameraInfo" and (camera.width, camera.height) == (640, 480)
    assert camera.k[0] == camera.k[4] == pytest.approx(530.0)  # no focal length known: the model's camera
    msgtype, _, cloud = clouds[0]
    assert msgtype == "sensor_msgs/msg/PointCloud2" and cloud.height == 1 and cloud.point_step == 16
    assert [(f.name, f.offset, f.datatype, f.count) for f in cloud.fields] == [
        ("x", 0, 7, 1),
        ("y", 4, 7, 1),
        ("z", 8, 7, 1),
        ("rgb", 12, 7, 1),
    ]
    assert cloud.width == 160 * 120 and len(cloud.data) == 16 * cloud.width  # stride 4, every pixel has depth


def test_a_ros2_bag_streams_with_its_stamps_camera_frame_and_sensor_depth(service, tmp_path):
    photos = sorted((MOSD / "color").glob("learn*.jpg"))[:4]
    frames = [
        (np.asarray(Image.open(p).convert("RGB")), np.asarray(Image.open(MOSD / "depth" / f"{p.stem}.png")))
        for p in photos
    ]
    # Stamps of today's size with odd nanoseconds: a float of seconds on the way would lose them.
    # A ROS 1 style frame id, "/camera": tf2 refuses the slash, so the bag's messages go without it.
    source = write_aligned_bag(tmp_path / "recording", "mcap", frames, start=1_764_000_000.123456789, frame="/camera")
    colour = read_bag(source)["/camera/color/image_raw"]
    assert stamp_ns(colour[1][2]) % 1000 != 0
    out = tmp_path / "streamed"
    stream_cli(service, str(source), "--bag", str(out), "--with-colour", "--with-sensor-depth", "--namespace", "/cam")
    topics = read_bag(out)
    depth = topics["/cam/aligned_depth_to_color/image_raw"]
    assert [stamp_ns(m) for _, _, m in depth] == [stamp_ns(m) for _, _, m in colour]
    assert {m.header.frame_id for _, _, m in depth} == {"camera"}  # the bag's own colour frame, without the slash
    # Every image topic has its CameraInfo: the photo's and the sensor depth's too, each at its image's size.
    for image, info_topic in (
        ("color/image_raw/compressed", "color/camera_info"),
        ("sensor/aligned_depth_to_color/image_raw", "sensor/aligned_depth_to_color/camera_info"),
    ):
        assert len(topics[f"/cam/{info_topic}"]) == len(topics[f"/cam/{image}"]) == len(depth), info_topic
    sensor_image, sensor_info = (
        topics["/cam/sensor/aligned_depth_to_color/image_raw"][0][2],
        topics["/cam/sensor/aligned_depth_to_color/camera_info"][0][2],
    )
    assert (sensor_info.width, sensor_info.height) == (sensor_image.width, sensor_image.height)
    (_, _, info), *_ = topics["/cam/aligned_depth_to_color/camera_info"]
    k = MOSD_CAMERA
    assert list(info.k) == pytest.approx([k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1])  # the recording's camera
    photo = topics["/cam/color/image_raw/compressed"][0][2]
    assert photo.format == "jpeg"
    with Image.open(io.BytesIO(photo.data.tobytes())) as im:
        assert im.size == (640, 480)
    # The depth in the bag is what /depth gives for the same photo and camera, to the millimetre.
    served = posted_depth(service, photo.data.tobytes(), fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy)
    first = depth[0][2]
    metres = np.frombuffer(first.data, dtype="<f4").reshape(first.height, first.width)
    np.testing.assert_array_equal(np.rint(np.nan_to_num(metres) * 1000), np.rint(served * 1000))
    # Carried as float32 end to end (the stream's raw32), not rounded to the millimetre on the way.
    fraction = np.abs(metres * 1000 - np.rint(metres * 1000))[np.isfinite(metres)]
    assert np.median(fraction) > 0.1
    # The cloud, decoded from its bytes: xyz and the packed rgb are /pointcloud's points, in its order.
    cloud = topics["/cam/depth/color/points"][0][2]
    records = np.frombuffer(cloud.data, dtype="<f4").reshape(-1, 4)
    params = {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy}
    response = httpx.post(f"{service}/pointcloud", files={"image": photo.data.tobytes()}, params=params, timeout=60)
    ply = PlyData.read(io.BytesIO(response.content))["vertex"]
    assert cloud.width == ply.count == len(records)
    np.testing.assert_array_equal(records[:, :3], np.stack([ply["x"], ply["y"], ply["z"]], axis=1))
    packed = records[:, 3].copy().view("<u4")
    unpacked = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], axis=1)
    np.testing.assert_array_equal(unpacked, np.stack([ply["red"], ply["green"], ply["blue"]], axis=1))
    sensor = topics["/cam/sensor/aligned_depth_to_color/image_raw"][0][2]
    sensor_m = np.frombuffer(sensor.data, dtype="<f4").reshape(480, 640)
    recorded = frames[0][1].astype(np.float64) / 1000
    assert np.isnan(sensor_m[recorded == 0]).all() and np.isnan(sensor_m).mean() > 0.2  # NaN where no reading
    np.testing.assert_allclose(sensor_m[recorded > 0], recorded[recorded > 0], atol=1e-6)


def test_a_folder_gives_png_and_ply_files_and_a_rerun_skips_them(service, tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    for i, photo in enumerate(KITCHEN[:3]):
        (folder / f"shot-{i * 5}.jpg").write_bytes(photo.read_bytes())  # shot-0, shot-5, shot-10: numeric order
    out = tmp_path / "out"
    first = stream_cli(service, str(folder), "--out", str(out), "--pointcloud", "--stride", "2")
    assert "3 frames written" in first.stdout
    by_time = sorted(out.glob("*.depth.png"), key=lambda f: f.stat().st_mtime_ns)
    assert [f.name for f in by_time] == ["shot-0.depth.png", "shot-5.depth.png", "shot-10.depth.png"]
    for i, photo in enumerate(KITCHEN[:3]):
        with Image.open(out / f"shot-{i * 5}.depth.png") as im:
            assert im.mode in ("I;16", "I") and im.size == (640, 480)
            np.testing.assert_array_equal(np.asarray(im) / 1000, posted_depth(service, photo.read_bytes()))
        ply = PlyData.read(out / f"shot-{i * 5}.ply")["vertex"]
        response = httpx.post(
            f"{service}/pointcloud", files={"image": photo.read_bytes()}, params={"stride": 2}, timeout=60
        )
        served = PlyData.read(io.BytesIO(response.content))["vertex"]
        assert ply.count == served.count == 320 * 240
        np.testing.assert_array_equal(ply["z"], served["z"])
    again = stream_cli(service, str(folder), "--out", str(out), "--pointcloud")
    assert "0 frames written" in again.stdout


def test_a_matroska_video_is_a_video_and_a_kinect_recording_is_a_recording(tmp_path):
    from recordings.formats import ReadOptions
    from recordings.sources import is_depth_recording, stream_source

    with av.open(str(tmp_path / "clip.mkv"), "w") as container:
        stream = container.add_stream("mpeg4", rate=30)
        stream.width, stream.height, stream.pix_fmt = 640, 480, "yuv420p"
        for photo in KITCHEN[:3]:
            container.mux(stream.encode(av.VideoFrame.from_image(Image.open(photo).convert("RGB"))))
        container.mux(stream.encode())
    assert not is_depth_recording(tmp_path / "clip.mkv")
    source = stream_source(str(tmp_path / "clip.mkv"), None, ReadOptions(max_frames=None), tmp_path / "scratch")
    assert len(list(source.frames)) == 3 and not source.live
    kinect = REPO.parent / "shared" / "data" / "captures"
    recorded = sorted(kinect.rglob("*.mkv"))
    assert recorded and is_depth_recording(recorded[0])  # the real Azure Kinect capture


def interruptible() -> None:
    """Ctrl-C as a terminal delivers it, even where this process was started with SIGINT ignored (a shell's
    background job): Python installs its handler only where SIGINT is not ignored at startup."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_mid_stream_leaves_a_bag_that_reads(service, tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    for n in range(850, 1000):
        (folder / f"{n}.jpg").write_bytes((SEVEN_SCENES / f"frame-{n:06d}.color.jpg").read_bytes())
    out = tmp_path / "bag"
    process = subprocess.Popen(
        [sys.executable, "-m", "cli", "stream", str(folder), "--bag", str(out), "--url", service],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=interruptible,
    )
    deadline = time.monotonic() + 120
    while sum(f.stat().st_size for f in out.glob("*.mcap")) < 20_000_000:  # a few frames in (~6 MB each)
        assert time.monotonic() < deadline and process.poll() is None, "the stream wrote nothing"
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    assert "stopped (Ctrl-C)" in stderr and "Traceback" not in stderr
    topics = read_bag(out)
    depth = topics["/rgb2cloud/aligned_depth_to_color/image_raw"]
    assert 0 < len(depth) < 150
    # Each frame whole or not at all: as many camera infos and clouds as depth images.
    assert len(topics["/rgb2cloud/aligned_depth_to_color/camera_info"]) == len(topics["/rgb2cloud/depth/color/points"])
    assert len(topics["/rgb2cloud/depth/color/points"]) == len(depth)


def test_bad_sources_and_options_are_one_line_errors(service, tmp_path):
    for args, says in [
        ([str(tmp_path / "nothing"), "--out", str(tmp_path / "o")], "no such file or folder"),
        ([str(tmp_path), "--out", str(tmp_path / "o")], "no photos"),
        ([str(KITCHEN[0].parent), "--bag", str(tmp_path / "b"), "--namespace", "camera"], "a ROS name starts with /"),
        ([str(KITCHEN[0].parent)], "nothing to write"),
        ([str(KITCHEN[0].parent), "--bag", str(tmp_path / "s"), "--with-sensor-depth"], "needs depth registered"),
    ]:
        result = stream_cli(service, *args, check=False)
        assert result.returncode == 1 and says in result.stderr and "Traceback" not in result.stderr, result.stderr


def loopback_devices() -> list[str]:
    names = Path("/sys/class/video4linux")
    if not names.is_dir():
        return []
    return [f"/dev/{d.name}" for d in names.iterdir() if "loopback" in (d / "name").read_text().lower()]


def test_a_webcam_through_v4l2loopback(service, tmp_path):
    devices = loopback_devices()
    if not devices:
        pytest.skip("no v4l2loopback device: this kernel offers none (it needs the module and root to load it)")
    if not (ffmpeg := os.popen("command -v ffmpeg").read().strip()):
        pytest.skip(f"{devices[0]} is a v4l2loopback device, but there is no ffmpeg to feed it frames")
    feeder = subprocess.Popen(
        [ffmpeg, "-re", "-stream_loop", "-1", "-i", str(KITCHEN[0]), "-f", "v4l2", "-pix_fmt", "yuv420p", devices[0]],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        process = subprocess.Popen(
            [sys.executable, "-m", "cli", "stream", devices[0], "--bag", str(tmp_path / "bag"), "--url", service],
            cwd=REPO,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=interruptible,
        )
        time.sleep(8)
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=60)
        assert len(read_bag(tmp_path / "bag")["/rgb2cloud/aligned_depth_to_color/image_raw"]) > 0
    finally:
        feeder.terminate()


def camera_infos(bag: Path) -> list:
    return [m for _, _, m in read_bag(bag)["/rgb2cloud/aligned_depth_to_color/camera_info"]]


def first_depth(bag: Path) -> np.ndarray:
    image = read_bag(bag)["/rgb2cloud/aligned_depth_to_color/image_raw"][0][2]
    return np.frombuffer(image.data, dtype="<f4").reshape(image.height, image.width)


def test_camera_overrides_are_in_the_recordings_own_pixels(service, tmp_path):
    # A 1280x720 bag whose CameraInfo says fx = fy = 1050, centre (639.5, 359.5). The reader writes its photos
    # smaller before they are streamed; whatever size is sent, K is the recording's camera scaled to it.
    frames = []
    for p in sorted((MOSD / "color").glob("learn*.jpg"))[:2]:
        rgb = Image.open(p).convert("RGB").resize((1280, 720), Image.Resampling.BILINEAR)
        mm = Image.open(MOSD / "depth" / f"{p.stem}.png").resize((1280, 720), Image.Resampling.NEAREST)
        frames.append((np.asarray(rgb), np.asarray(mm)))
    from contract.geometry import Intrinsics

    source = write_aligned_bag(tmp_path / "hd", "mcap", frames, info=Intrinsics(1050, 1050, 639.5, 359.5, 1280, 720))
    runs = {"recorded": [], "said again": ["--fx", "1050"], "other": ["--fx", "700", "--cx", "600"]}
    for name, args in runs.items():
        stream_cli(service, str(source), "--bag", str(tmp_path / name), *args)
    for name, fx, cx in (("recorded", 1050, 639.5), ("said again", 1050, 639.5), ("other", 700, 600)):
        for info in camera_infos(tmp_path / name):
            w, h = info.width, info.height
            assert w < 1280 and w * 720 == pytest.approx(h * 1280, rel=0.01)  # sent smaller, the same shape
            # By hand: a focal length scales with the width, a pixel centre c goes to (c + 0.5) * w / 1280 - 0.5.
            assert info.k[0] / w == pytest.approx(fx / 1280, rel=1e-6), name
            assert info.k[4] / h == pytest.approx(1050 / 720, rel=1e-6), name
            assert info.k[2] == pytest.approx((cx + 0.5) * w / 1280 - 0.5, abs=1e-6), name
            assert info.k[5] == pytest.approx(360 * h / 720 - 0.5, abs=1e-6), name
            assert info.p[0] == info.k[0] and info.p[2] == info.k[2]
    recorded, said_again = first_depth(tmp_path / "recorded"), first_depth(tmp_path / "said again")
    np.testing.assert_array_equal(recorded, said_again)  # the same camera said again: the same depth
    assert not np.allclose(recorded, first_depth(tmp_path / "other"), equal_nan=True)


def test_each_frame_of_a_manifest_goes_with_its_own_camera(service, tmp_path):
    # Three rows, three cameras, two sizes: each frame's CameraInfo is its own row's, at the size sent.
    rows = [(850, (640, 480), (530, 531, 319.5, 239.5)), (851, (320, 240), (300, 310, 150, 120))]
    rows.append((852, (640, 480), (600, 600, 330, 250)))
    lines = ["rgb,depth,depth_scale,fx,fy,cx,cy"]
    for n, size, (fx, fy, cx, cy) in rows:
        rgb, depth = tmp_path / f"{n}.png", tmp_path / f"{n}.depth.png"
        Image.open(SEVEN_SCENES / f"frame-{n:06d}.color.jpg").resize(size, Image.Resampling.BILINEAR).save(rgb)
        Image.open(SEVEN_SCENES / f"frame-{n:06d}.depth.png").resize(size, Image.Resampling.NEAREST).save(depth)
        lines.append(f"{rgb.name},{depth.name},1000,{fx},{fy},{cx},{cy}")
    (tmp_path / "rows.csv").write_text("\n".join(lines) + "\n")
    stream_cli(service, str(tmp_path / "rows.csv"), "--bag", str(tmp_path / "bag"))
    infos = camera_infos(tmp_path / "bag")
    assert len(infos) == 3
    for info, (_, size, (fx, fy, cx, cy)) in zip(infos, rows, strict=True):
        assert (info.width, info.height) == size  # under the stream's limit: sent as they are
        assert list(info.k) == pytest.approx([fx, 0, cx, 0, fy, cy, 0, 0, 1])


def test_a_12_megapixel_photo_is_sent_resized_with_its_camera(service, tmp_path):
    folder = tmp_path / "phone"
    folder.mkdir()
    Image.open(KITCHEN[0]).resize((4032, 3024), Image.Resampling.BILINEAR).save(folder / "big.jpg", quality=90)
    result = stream_cli(
        service,
        str(folder),
        "--out",
        str(tmp_path / "out"),
        "--bag",
        str(tmp_path / "bag"),
        "--fx",
        "3000",
        "--stride",
        "16",
    )
    assert result.stderr.count("over the stream's 8,294,400 pixels") == 1, result.stderr
    with Image.open(tmp_path / "out" / "big.depth.png") as im:
        w, h = im.size
    # By hand: sqrt(8294400 / (4032 * 3024)) = 0.8248, so 3325 x 2494, under the limit with its shape kept.
    assert (w, h) == (3325, 2494) and w * h <= 3840 * 2160
    (info,) = camera_infos(tmp_path / "bag")
    assert (info.width, info.height) == (w, h)
    assert info.k[0] == pytest.approx(3000 * w / 4032, rel=1e-6)  # --fx is in the photo's own pixels
    assert info.k[4] == pytest.approx(3000 * h / 3024, rel=1e-6)  # fy, not given, is fx in the photo's pixels


def test_a_resized_phone_photo_keeps_its_exif_orientation_and_focal_length(service, tmp_path):
    # Stored 4032x3024, turned a quarter (EXIF orientation 6: upright it is 3024x4032), a 26 mm lens in
    # 35 mm film terms, and no --fx: the service reads the camera from the EXIF, as POST /depth does.
    folder = tmp_path / "phone"
    folder.mkdir()
    exif = Image.Exif()
    exif[ExifTags.Base.Orientation] = 6
    exif.get_ifd(ExifTags.IFD.Exif)[ExifTags.Base.FocalLengthIn35mmFilm] = 26
    photo = Image.open(KITCHEN[0]).resize((4032, 3024), Image.Resampling.BILINEAR)
    photo.save(folder / "portrait.jpg", quality=90, exif=exif)
    stream_cli(service, str(folder), "--out", str(tmp_path / "out"), "--bag", str(tmp_path / "bag"))
    with Image.open(tmp_path / "out" / "portrait.depth.png") as im:
        assert im.size == (2494, 3325)  # upright, at 0.8248 of each side (as above)
    (info,) = camera_infos(tmp_path / "bag")
    # By hand: f35 x the photo's diagonal in pixels / the film's 43.27 mm diagonal = 2497.7 px.
    f = 26 * math.hypot(2494, 3325) / math.hypot(36, 24)
    assert info.k[0] == pytest.approx(f, rel=1e-3) and info.k[4] == pytest.approx(f, rel=1e-3)


def test_a_busy_service_refuses_frames_with_503_and_the_stream_sends_them_again(tmp_path):
    # One request at a time and no queue. Another client's stream of 4K frames holds the one worker (a stream's
    # next frame waits in the service, so it takes the worker the moment its last lets go) until the service has
    # refused a frame of ours with 503, then ends, as a shared service's other clients come and go.
    folder = tmp_path / "photos"
    folder.mkdir()
    for i, photo in enumerate(KITCHEN[:12]):
        (folder / f"{i:02d}.jpg").write_bytes(photo.read_bytes())
    env = {"bundled_registry": BUNDLED_REGISTRY, "model": "rgb2cloud-7scenes", "engine": "onnxruntime"}

    def refused(url: str) -> float:
        lines = httpx.get(f"{url}/metrics").text.splitlines()
        counts = [line for line in lines if line.startswith('rgb2cloud_stream_frames_total{outcome="refused"')]
        return float(counts[0].split()[-1]) if counts else 0.0

    large = io.BytesIO()
    Image.open(KITCHEN[20]).resize((3840, 2160)).save(large, format="JPEG", quality=90)
    with running_service(**env, workers="1", max_queue="0") as up:
        holding = threading.Event()

        def frames() -> Iterator[bytes]:
            while not refused(up.url):
                yield large.getvalue()

        def other_client() -> None:
            with open_stream(up.url, output="both", cloud_encoding="raw") as socket:
                for _ in answers(socket, frames(), lambda frame: frame, live=False):
                    holding.set()

        other = threading.Thread(target=other_client)
        other.start()
        try:
            assert holding.wait(timeout=60), "the other client's stream got no answer"
            result = stream_cli(up.url, str(folder), "--out", str(tmp_path / "out"))
        finally:
            other.join(timeout=120)
    assert "12 frames written" in result.stdout and "refused" not in result.stdout, result.stdout
    assert "sent again while the service was busy" in result.stdout  # 503s happened to our frames...
    assert len(list((tmp_path / "out").glob("*.depth.png"))) == 12  # ...and every frame still came back


class Closing:
    """A sink whose close fails with ``error`` (None: closes), and notes that it was closed."""

    def __init__(self, error: Exception | None = None):
        self.error, self.closed = error, False

    def close(self) -> None:
        self.closed = True
        if self.error is not None:
            raise self.error


def test_every_output_is_closed_and_a_failure_to_close_never_hides_the_error_on_its_way_up():
    from cli.stream_loop import close_all

    # Nothing on its way up: every sink is closed, the first failure is raised, the others are said.
    sinks, said = [Closing(OSError("disk full")), Closing(), Closing(ValueError("second"))], []
    with pytest.raises(OSError, match="disk full"):
        close_all(sinks, said.append)
    assert all(sink.closed for sink in sinks) and said == ["also, an output failed to close: second"]

    # An error on its way up (as from the stream, closing in a finally): it stays the one raised.
    sinks, said = [Closing(OSError("disk full")), Closing()], []
    with pytest.raises(KeyboardInterrupt):
        try:
            raise KeyboardInterrupt
        finally:
            close_all(sinks, said.append)
    assert all(sink.closed for sink in sinks) and said == ["also, an output failed to close: disk full"]


def test_unreadable_photos_are_named_and_skipped_and_the_stream_goes_on(service, tmp_path):
    folder, out = tmp_path / "photos", tmp_path / "out"
    folder.mkdir()
    good = [KITCHEN[i].read_bytes() for i in range(4)]
    (folder / "shot-0.jpg").write_bytes(good[0])
    (folder / "shot-1.jpg").write_bytes(np.random.default_rng(0).bytes(5000))  # random bytes named .jpg
    (folder / "shot-2.jpg").write_bytes(good[1])
    (folder / "shot-3.png").write_bytes(png_header(20_000, 20_000))  # 400 MP: over the bomb limit
    (folder / "shot-4.jpg").write_bytes(good[2])
    (folder / "shot-5.jpg").write_bytes(good[3][: len(good[3]) // 2])  # cut off halfway
    result = stream_cli(service, str(folder), "--out", str(out), check=False)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    assert "shot-1: skipped, not an image Pillow can read" in result.stderr
    assert "shot-3: skipped, over Pillow's decompression-bomb limit of" in result.stderr
    # The client sends a photo it need not resize as it is: the service decodes it, and refuses the cut one.
    assert "shot-5: 400: " in result.stderr
    assert (
        result.stdout.strip().splitlines()[-1] == "3 frames written, 1 refused by the service, 2 skipped as unreadable"
    )
    assert sorted(p.name for p in out.glob("*.depth.png")) == [f"shot-{i}.depth.png" for i in (0, 2, 4)]


class FailingSink:
    """A sink whose every write fails, as a full disk would fail it."""

    def write(self, frame) -> None:
        raise OSError("no space left on device")

    def close(self) -> None:
        pass


@pytest.mark.parametrize("stream_breaks", [False, True])
def test_a_writer_failure_never_replaces_the_error_on_its_way_up(monkeypatch, capsys, stream_breaks):
    """One answer is written (and fails); then the stream ends, or breaks. A break is what is raised, the
    writer's failure said beside it; an end raises the writer's failure. Either way every answer is counted."""
    from websockets.exceptions import ConnectionClosedError

    import clients.stream as client
    from cli.stream_loop import Tally, run_stream
    from recordings.sources import Source, SourceFrame

    def one_answer(socket, sending, encode, live, options_of=None):
        item = next(iter(sending))
        yield client.Answer(item, {"type": "frame", "skipped": 0, "payloads": []}, {})
        if stream_breaks:
            raise ConnectionClosedError(None, None)

    monkeypatch.setattr(client, "open_stream", lambda url, **options: contextlib.nullcontext())
    monkeypatch.setattr(client, "answers", one_answer)
    monkeypatch.setattr("clients.sinks.decoded", lambda frame, header, payloads: frame)  # no payloads to decode
    frames = iter([SourceFrame("shot-0", 0, KITCHEN[0].read_bytes())])
    tally = Tally()
    expected = ConnectionClosedError if stream_breaks else OSError
    with pytest.raises(expected):
        run_stream(Source(frames, live=False), "http://127.0.0.1:9", [FailingSink()], {}, {}, 10**8, tally)
    said = capsys.readouterr().err
    assert ("also, an output failed: no space left on device" in said) == stream_breaks
    assert tally.written == 0 and tally.summary() == "0 frames written"


def test_a_writer_failure_met_by_the_next_answer_is_raised_once(monkeypatch, capsys):
    """The first answer's write fails; the second answer meets that failure on its way to the writer: it is the
    error raised, and it is not said a second time as "also"."""
    import threading

    import clients.stream as client
    from cli.stream_loop import Tally, run_stream
    from recordings.sources import Source, SourceFrame

    failed = threading.Event()

    class Full(FailingSink):
        def write(self, frame) -> None:
            failed.set()
            super().write(frame)

    def two_answers(socket, sending, encode, live, options_of=None):
        items = iter(sending)
        yield client.Answer(next(items), {"type": "frame", "skipped": 0, "payloads": []}, {})
        assert failed.wait(10)
        time.sleep(0.2)  # the writer's thread stores its failure right after the write raised
        yield client.Answer(next(items), {"type": "frame", "skipped": 0, "payloads": []}, {})

    monkeypatch.setattr(client, "open_stream", lambda url, **options: contextlib.nullcontext())
    monkeypatch.setattr(client, "answers", two_answers)
    monkeypatch.setattr("clients.sinks.decoded", lambda frame, header, payloads: frame)
    photo = KITCHEN[0].read_bytes()
    frames = iter([SourceFrame("shot-0", 0, photo), SourceFrame("shot-1", 1, photo)])
    with pytest.raises(OSError, match="no space left on device"):
        run_stream(Source(frames, live=False), "http://127.0.0.1:9", [Full()], {}, {}, 10**8, Tally())
    assert "also, an output failed" not in capsys.readouterr().err


def test_a_stream_to_nothing_listening_is_one_line(capsys):
    """A refused connection is a one-line error naming the URL, and no progress bar is left behind."""
    from cli.stream_loop import Tally, run_stream
    from contract.errors import UserError
    from recordings.sources import Source, SourceFrame

    frames = iter([SourceFrame("shot-0", 0, KITCHEN[0].read_bytes())])
    with pytest.raises(UserError, match=r"^http://127.0.0.1:9: cannot open the stream: ") as refused:
        run_stream(Source(frames, live=False), "http://127.0.0.1:9", [FailingSink()], {}, {}, 10**8, Tally())
    assert "\n" not in str(refused.value)
    assert "stream:" not in capsys.readouterr().err  # no bar was drawn


def test_the_stream_client_refuses_a_message_larger_than_an_answer_can_be():
    """A URL that is no rgb2cloud stream cannot fill the client's memory: a message over what an answer to a
    photo of ``max_pixels`` holds (a point cloud of 15 bytes a pixel) closes the connection (1009)."""
    from websockets.exceptions import ConnectionClosedError
    from websockets.sync.server import serve

    def flood(socket) -> None:
        socket.send(b"\0" * (16 * 100))  # as large as an answer to 100 pixels may be
        socket.send(b"\0" * (16 * 100 + 1))
        socket.recv()

    with serve(flood, "127.0.0.1", 0) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        url = f"http://127.0.0.1:{server.socket.getsockname()[1]}"
        with open_stream(url, max_pixels=100) as socket:
            assert len(socket.recv(timeout=10)) == 1600
            with pytest.raises(ConnectionClosedError) as closed:
                socket.recv(timeout=10)
        assert closed.value.sent.code == 1009  # "message too big"
