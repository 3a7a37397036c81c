"""Broken recordings, as real sensors and real disks leave them: each is one line that names the file.

Every file is written with its format's own library (rosbags, PyAV, zipfile with LZFSE, PIL) from
real mOSD frames, then damaged the way a killed recorder, a full disk or a wrong export damages it.
A broken container is refused in one line that names it; a few broken frames among many are skipped
and named, and the rest are read. ``fit``'s command line prints a ``UserError`` as one ``error:``
line with a non-zero exit (``test_a_broken_recording_is_one_error_line_from_fit``).
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO
from PIL import Image

from contract.errors import UserError
from harness.recordings import MOSD_CAMERA, BagWriter, write_aligned_bag, write_record3d, write_stray_scanner
from recordings.folders import CameraFile
from recordings.formats import ReadOptions, open_recording
from trainer.fit.inspect import readable

MOSD = REPO.parent / "shared" / "data" / "mosd-tabletop"


def mosd_frames(count: int, scale: float = 0.25) -> list[tuple[np.ndarray, np.ndarray]]:
    """Real colour and millimetre depth, ``scale`` of 640x480."""
    frames = []
    for colour in sorted((MOSD / "color").glob("learn*.jpg"))[:count]:
        size = (round(640 * scale), round(480 * scale))
        rgb = np.asarray(Image.open(colour).convert("RGB").resize(size, Image.BILINEAR))
        depth = Image.open(MOSD / "depth" / f"{colour.stem}.png").resize(size, Image.NEAREST)
        frames.append((rgb, np.asarray(depth, dtype=np.uint16)))
    return frames


def read(path: Path, tmp_path: Path, options: ReadOptions | None = None):
    """The recording as fit opens it, its unreadable pairs set aside."""
    return readable(open_recording(path, None, options or ReadOptions(), tmp_path / "scratch"))


def refused(path: Path, tmp_path: Path, options: ReadOptions | None = None) -> str:
    with pytest.raises(UserError) as error:
        read(path, tmp_path, options)
    message = str(error.value)
    assert "\n" not in message
    return message


# --- damage, done to files the formats' own writers wrote ---------------------------------------------


def mcap_records(data: bytes, start: int, end: int) -> list[tuple[int, int, int]]:
    """(opcode, offset, length) of the MCAP records between ``start`` and ``end``."""
    records, at = [], start
    while at + 9 <= end:
        opcode, length = data[at], struct.unpack_from("<Q", data, at + 1)[0]
        records.append((opcode, at, length))
        at += 9 + length
        if opcode == 0x0F:  # the footer
            break
    return records


def damage_mcap_chunk(path: Path) -> None:
    """A message inside the first chunk claims more bytes than the chunk holds (a recorder killed mid-write)."""
    data = bytearray(path.read_bytes())
    _, chunk, length = next(r for r in mcap_records(data, 8, len(data)) if r[0] == 0x06)
    body = chunk + 9
    compression = struct.unpack_from("<I", data, body + 28)[0]
    records = body + 28 + 4 + compression + 8
    messages = [r for r in mcap_records(data, records, chunk + 9 + length) if r[0] == 0x05]
    struct.pack_into("<Q", data, messages[1][1] + 1, 2**40)
    path.write_bytes(bytes(data))


def damage_ros1_chunk(path: Path) -> None:
    """A record inside the first chunk of a ROS 1 bag claims 2 GB."""
    data = bytearray(path.read_bytes())
    at = 13  # after "#ROSBAG V2.0\n"
    while True:
        header_length = struct.unpack_from("<I", data, at)[0]
        header = bytes(data[at + 4 : at + 4 + header_length])
        data_length = struct.unpack_from("<I", data, at + 4 + header_length)[0]
        if b"op=\x05" in header:
            break
        at += 8 + header_length + data_length
    inner = at + 8 + header_length
    for _ in range(5):  # past the connection records to a message's
        inner_header = struct.unpack_from("<I", data, inner)[0]
        inner += 8 + inner_header + struct.unpack_from("<I", data, inner + 4 + inner_header)[0]
    inner_header = struct.unpack_from("<I", data, inner)[0]
    struct.pack_into("<I", data, inner + 4 + inner_header, 2**31)
    path.write_bytes(bytes(data))


def bag_with_info(path: Path, **info) -> Path:
    """An aligned ROS 1 bag whose colour CameraInfo is written with ``info`` (distortion, size, uncalibrated)."""
    frames = mosd_frames(2)
    k = MOSD_CAMERA.resized(160, 120)
    with BagWriter(path, "ros1") as bag:
        for i, (rgb, mm) in enumerate(frames):
            t = 1.0 + i / 30
            bag.image("/camera/color/image_raw", t, rgb, "rgb8")
            bag.camera_info("/camera/color/camera_info", t, k, **info)
            bag.image("/camera/aligned_depth_to_color/image_raw", t, mm, "16UC1")
            bag.camera_info("/camera/aligned_depth_to_color/camera_info", t, k)
    return path


def stray(tmp_path: Path, count: int = 4) -> Path:
    return write_stray_scanner(tmp_path / "scan", mosd_frames(count, 0.5), MOSD_CAMERA.resized(320, 240))


def r3d(tmp_path: Path, count: int = 4, **metadata) -> Path:
    path = write_record3d(tmp_path / "scan.r3d", mosd_frames(count, 0.5), MOSD_CAMERA.resized(320, 240))
    if metadata:
        with zipfile.ZipFile(path) as archive:
            members = {name: archive.read(name) for name in archive.namelist()}
        members["metadata"] = json.dumps({**json.loads(members["metadata"]), **metadata}).encode()
        with zipfile.ZipFile(path, "w") as archive:
            for name, data in members.items():
                archive.writestr(name, data)
    return path


def folders(tmp_path: Path, count: int = 6) -> Path:
    root = tmp_path / "rec"
    (root / "color").mkdir(parents=True)
    (root / "depth").mkdir()
    for i, (rgb, mm) in enumerate(mosd_frames(count)):
        Image.fromarray(rgb).save(root / "color" / f"{i:03d}.jpg")
        Image.fromarray(mm).save(root / "depth" / f"{i:03d}.png")
    k = MOSD_CAMERA.resized(160, 120)
    (root / "intrinsics.json").write_text(json.dumps({"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy}))
    return root


# --- containers that cannot be read: one line naming the file ------------------------------------------


def test_an_mcap_with_a_damaged_chunk(tmp_path):
    bag = write_aligned_bag(tmp_path / "rec", "mcap", mosd_frames(3))
    damage_mcap_chunk(next(bag.glob("*.mcap")))
    assert refused(bag, tmp_path) == f"{bag}: damaged: a record claims more bytes than the file holds"


def test_a_ros1_bag_with_a_damaged_chunk(tmp_path):
    bag = write_aligned_bag(tmp_path / "rec.bag", "ros1", mosd_frames(3))
    damage_ros1_chunk(bag)
    assert refused(bag, tmp_path) == f"{bag}: damaged: a record claims more bytes than the file holds"


@pytest.mark.parametrize("compression", ["LZ4", "BZ2"])
def test_a_compressed_ros1_bag_whose_chunk_fails_to_decompress(tmp_path, monkeypatch, compression):
    """rosbags writes the chunks compressed; bytes flipped inside one make lz4 or bz2 fail, in words."""
    import harness.recordings

    class Compressed(harness.recordings.Ros1Writer):
        def __init__(self, path: Path):
            super().__init__(path)
            self.set_compression(getattr(self.CompressionFormat, compression))

    monkeypatch.setattr(harness.recordings, "Ros1Writer", Compressed)
    bag = write_aligned_bag(tmp_path / "rec.bag", "ros1", mosd_frames(3))
    data = bytearray(bag.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 64] = bytes(b ^ 0xFF for b in data[middle : middle + 64])
    bag.write_bytes(bytes(data))
    message = refused(bag, tmp_path)
    assert message.startswith(f"{bag}: damaged: ") and "Error" not in message and "0x" not in message, message


def test_an_mcap_whose_zstd_chunk_is_damaged(tmp_path, monkeypatch):
    """MCAP's chunks compressed with zstd (rosbags' storage compression): damaged, they are said in words."""
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

    import harness.recordings

    class Compressed(harness.recordings.Ros2Writer):
        def __init__(self, path: Path, **options):
            super().__init__(path, **options)
            self.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)

    monkeypatch.setattr(harness.recordings, "Ros2Writer", Compressed)
    bag = write_aligned_bag(tmp_path / "rec", "mcap", mosd_frames(3))
    file = next(bag.glob("*.mcap"))
    data = bytearray(file.read_bytes())
    _, chunk, length = next(r for r in mcap_records(data, 8, len(data)) if r[0] == 0x06)
    middle = chunk + 9 + length // 2
    data[middle : middle + 64] = bytes(b ^ 0xFF for b in data[middle : middle + 64])
    file.write_bytes(bytes(data))
    message = refused(bag, tmp_path)
    assert message.startswith(f"{bag}: damaged: ") and "Error" not in message, message


def test_a_full_disk_while_writing_frames_is_not_called_damage(tmp_path, monkeypatch):
    """A failed write is the disk's, not the bag's: it keeps its own error and traceback."""
    import errno

    import recordings.pair_writer

    def full(*_, **__):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(recordings.pair_writer.PairWriter, "photo", full)
    bag = write_aligned_bag(tmp_path / "rec.bag", "ros1", mosd_frames(2))
    with pytest.raises(OSError, match="No space left on device") as error:
        read(bag, tmp_path)
    assert not isinstance(error.value, UserError)


def test_a_bug_in_the_bag_reader_keeps_its_traceback(tmp_path, monkeypatch):
    """Only what the bag libraries raise for damaged bytes becomes one line: a bug is not called damage."""
    import recordings.rosbag

    def broken(*_):
        raise KeyError("a bug")

    monkeypatch.setattr(recordings.rosbag, "_pair", broken)
    bag = write_aligned_bag(tmp_path / "rec.bag", "ros1", mosd_frames(2))
    with pytest.raises(KeyError, match="a bug"):
        read(bag, tmp_path)


def test_a_ros2_bag_whose_database_is_damaged(tmp_path):
    bag = write_aligned_bag(tmp_path / "rec", "ros2", mosd_frames(3))
    database = next(bag.glob("*.db3"))
    data = bytearray(database.read_bytes())
    data[100:4096] = b"\xff" * (4096 - 100)  # the database header and first page
    database.write_bytes(bytes(data))
    assert str(bag) in refused(bag, tmp_path)


def test_a_truncated_mcap(tmp_path):
    bag = write_aligned_bag(tmp_path / "rec", "mcap", mosd_frames(3))
    file = next(bag.glob("*.mcap"))
    file.write_bytes(file.read_bytes()[: file.stat().st_size // 2])
    assert refused(bag, tmp_path).startswith(f"{bag}: ")


def test_a_record3d_export_whose_camera_matrix_is_malformed(tmp_path):
    path = r3d(tmp_path, K=[500.0, 0, 0, 0, 500.0])
    assert (
        refused(path, tmp_path) == f"{path}: its metadata's K is [500.0, 0, 0, 0, 500.0], not 9 numbers (a 3x3 matrix)"
    )


def test_a_record3d_export_whose_sizes_are_not_numbers(tmp_path):
    path = r3d(tmp_path, w="1920")
    assert refused(path, tmp_path) == f"{path}: its metadata's w is '1920', not a positive whole number of pixels"


def test_a_truncated_record3d_export(tmp_path):
    path = r3d(tmp_path)
    path.write_bytes(path.read_bytes()[:-300])
    assert refused(path, tmp_path).startswith(f"{path}: not a complete .r3d (zip) file")


def test_a_stray_scanner_export_without_its_video(tmp_path):
    root = stray(tmp_path)
    (root / "rgb.mp4").unlink()
    assert (
        refused(root, tmp_path) == f"{root / 'rgb.mp4'}: missing; a Stray Scanner export holds its colour video there"
    )


def test_a_stray_scanner_export_whose_video_is_garbage(tmp_path):
    root = stray(tmp_path)
    (root / "rgb.mp4").write_bytes(b"\0\0\0\x18ftypmp42" + b"\x13" * 500)
    assert refused(root, tmp_path).startswith(f"{root / 'rgb.mp4'}: no frame could be decoded")


def test_an_eight_bit_depth_png_is_called_eight_bit_whatever_the_depth_scale(tmp_path):
    root = folders(tmp_path)
    millimetres = np.asarray(Image.open(root / "depth" / "000.png"))
    Image.fromarray((millimetres // 16).clip(0, 255).astype(np.uint8)).save(root / "depth" / "000.png")
    message = refused(root, tmp_path, ReadOptions(camera=CameraFile(depth_scale=100.0)))
    assert message.startswith(f"{root / 'depth' / '000.png'}: an 8-bit greyscale image, not 16-bit depth")


def test_a_colour_depth_png_is_refused(tmp_path):
    root = folders(tmp_path)
    Image.open(root / "color" / "002.jpg").save(root / "depth" / "002.png")
    assert "an 8-bit colour image, not 16-bit depth" in refused(root, tmp_path)


def test_a_folder_of_unknown_layout_lists_every_layout_fit_reads(tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.txt").write_text("x")
    message = refused(tmp_path / "photos", tmp_path)
    assert "cannot tell its layout" in message and "Stray Scanner" in message and "Record3D" in message


@pytest.mark.parametrize(
    ("info", "says"),
    [
        ({"uncalibrated": True}, "/camera/color/camera_info: the camera matrix K is all zeros, not a calibration"),
        ({"size": (200, 120)}, "/camera/color/camera_info describes 200x120 images, but /camera/color/image_raw's"),
        ({"distortion": ("fov", (0.1,))}, "lens distortion model 'fov' cannot be undone here"),
    ],
)
def test_a_bag_whose_camera_info_cannot_be_right(tmp_path, info, says):
    bag = bag_with_info(tmp_path / "rec.bag", **info)
    message = refused(bag, tmp_path)
    assert message.startswith(f"{bag}: ") and says in message


def test_a_topic_of_the_wrong_kind_is_named(tmp_path):
    bag = write_aligned_bag(tmp_path / "rec.bag", "ros1", mosd_frames(2))
    options = ReadOptions(color_topic="/camera/aligned_depth_to_color/image_raw")
    message = refused(bag, tmp_path, options)
    assert message.startswith(f"{bag}: --color-topic /camera/aligned_depth_to_color/image_raw: its images are depth")


def test_several_colour_topics_name_the_option_that_chooses(tmp_path):
    frames = mosd_frames(2)
    k = MOSD_CAMERA.resized(160, 120)
    with BagWriter(tmp_path / "two.bag", "ros1") as bag:
        for topic in ("/left/color/image_raw", "/right/color/image_raw"):
            bag.image(topic, 1.0, frames[0][0], "rgb8")
            bag.camera_info(topic.replace("image_raw", "camera_info"), 1.0, k)
        bag.image("/left/depth/image_raw", 1.0, frames[0][1], "16UC1")
    assert refused(tmp_path / "two.bag", tmp_path).endswith("pass --color-topic")


def test_a_depth_scale_for_metres_is_refused(tmp_path):
    bag = write_aligned_bag(tmp_path / "rec.bag", "ros1", mosd_frames(2), depth="32FC1")
    message = refused(bag, tmp_path, ReadOptions(camera=CameraFile(depth_scale=1000.0)))
    assert message.endswith("holds 32FC1 depth, which is metres by definition")


def test_a_depth_scale_for_a_phone_export_is_refused(tmp_path):
    message = refused(r3d(tmp_path), tmp_path, ReadOptions(camera=CameraFile(depth_scale=1000.0)))
    assert message.endswith("--depth-scale does not apply to a record3d recording: its format fixes the units")


# --- a few broken frames among many: skipped, named, and the rest read ---------------------------------


def test_a_corrupt_depth_png_among_many_is_skipped_and_named(tmp_path):
    root = folders(tmp_path)
    (root / "depth" / "003.png").write_bytes((root / "depth" / "003.png").read_bytes()[:200])
    recording = read(root, tmp_path)
    assert [p.name for p in recording.pairs] == ["000", "001", "002", "004", "005"]
    assert recording.skipped[0] == ("003", "damaged: not a readable image")


def test_a_truncated_photo_among_many_is_skipped_and_named(tmp_path):
    root = folders(tmp_path)
    (root / "color" / "001.jpg").write_bytes((root / "color" / "001.jpg").read_bytes()[:100])
    recording = read(root, tmp_path)
    assert len(recording.pairs) == 5 and recording.skipped[0][0] == "001"


def test_a_record3d_photo_that_cannot_be_decoded_is_named_by_its_entry(tmp_path):
    path = r3d(tmp_path)
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members["rgbd/2.jpg"] = members["rgbd/2.jpg"][:50]
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    recording = read(path, tmp_path)
    assert len(recording.pairs) == 3
    (name, why), *_ = recording.skipped
    assert (name, why) == ("2", "damaged: rgbd/2.jpg is not a readable JPEG")


def test_a_cut_short_video_names_the_file_and_where_it_ends(tmp_path):
    root = stray(tmp_path, count=5)
    for extra in range(5, 8):  # depth maps for frames the video never got
        Image.open(root / "depth" / "000000.png").save(root / "depth" / f"{extra:06d}.png")
    recording = read(root, tmp_path)
    assert len(recording.pairs) == 5
    assert recording.skipped[0] == (
        "000005",
        "the video has no frame with this number (rgb.mp4 ends after 5 frames: cut short?)",
    )


def test_a_damaged_compressed_photo_in_a_bag_is_skipped_and_named(tmp_path):
    frames = mosd_frames(3)
    k = MOSD_CAMERA.resized(160, 120)
    with BagWriter(tmp_path / "rec.bag", "ros1") as bag:
        for i, (rgb, mm) in enumerate(frames):
            t = 1.0 + i / 30
            if i == 1:  # a JPEG whose data stops after its header
                good = bag.jpeg("/unused/image_raw/compressed", t, rgb)
                message = bag.store.types["sensor_msgs/msg/CompressedImage"](
                    header=bag._header(t, "camera"), format="jpeg", data=np.frombuffer(good[:300], np.uint8)
                )
                bag.write("/camera/color/image_raw/compressed", "sensor_msgs/msg/CompressedImage", t, message)
            else:
                bag.jpeg("/camera/color/image_raw/compressed", t, rgb)
            bag.camera_info("/camera/color/camera_info", t, k)
            bag.image("/camera/aligned_depth_to_color/image_raw", t, mm, "16UC1")
            bag.camera_info("/camera/aligned_depth_to_color/camera_info", t, k)
    recording = read(tmp_path / "rec.bag", tmp_path, ReadOptions(color_topic="/camera/color/image_raw/compressed"))
    assert len(recording.pairs) == 2
    assert recording.skipped == [(f"{1 + 1 / 30:.6f}", recording.skipped[0][1])]
    assert recording.skipped[0][1] == "colour frame damaged: not a readable JPEG or PNG"


def test_a_broken_recording_is_one_error_line_from_fit(tmp_path):
    bag = write_aligned_bag(tmp_path / "rec", "mcap", mosd_frames(3))
    damage_mcap_chunk(next(bag.glob("*.mcap")))
    args = ["fit", str(bag), "--name", "x", "--licence", "test", "--out", str(tmp_path / "run")]
    result = subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, capture_output=True, text=True, timeout=60)
    lines = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert len(lines) == 1 and lines[0].startswith(f"error: {bag}: damaged")
    assert "--resume" not in result.stderr


def test_too_few_pairs_left_names_why_the_others_were_skipped(tmp_path):
    """A cut-short video is not blamed on the recording's length: the error names the file and where it ended."""
    root = stray(tmp_path, count=12)
    for extra in range(12, 21):  # depth maps for frames the video never got
        Image.open(root / "depth" / "000000.png").save(root / "depth" / f"{extra:06d}.png")
    args = ["fit", str(root), "--name", "x", "--licence", "test", "--out", str(tmp_path / "run")]
    result = subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, capture_output=True, text=True, timeout=120)
    last = result.stderr.strip().splitlines()[-1]
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert last == (
        f"error: {root}: 12 usable pairs, fit needs at least 20; 9 skipped, e.g. 000012: the video has no frame "
        "with this number (rgb.mp4 ends after 12 frames: cut short?)"
    )
