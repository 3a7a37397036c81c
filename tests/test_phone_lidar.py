"""Phone LiDAR recordings (Stray Scanner, Record3D) as fit reads them: the real iPhone frame's depth upsampling,
and exports written with PyAV's video encoder and LZFSE from real mOSD frames."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import DATA, REPO, run_cli
from PIL import Image

from contract.card import load_card
from contract.errors import UserError
from contract.geometry import ColourCamera, Intrinsics
from harness.recordings import MOSD_CAMERA, write_record3d, write_stray_scanner
from recordings.folders import CameraFile
from recordings.formats import ReadOptions, detect_format, open_recording
from recordings.frames import Frame
from recordings.record3d import read_record3d
from recordings.registration import SURFACE_SPREAD, alignment, upsample_depth
from recordings.strayscanner import read_stray_scanner

IPHONE = DATA / "captures" / "iphone-lidar"
MOSD = DATA / "mosd-tabletop"


def mosd_frames(count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    frames = []
    for colour in sorted((MOSD / "color").glob("learn*.jpg"))[:count]:
        depth = np.asarray(Image.open(MOSD / "depth" / f"{colour.stem}.png"), dtype=np.uint16)
        frames.append((np.asarray(Image.open(colour).convert("RGB")), depth))
    return frames


def between_surfaces(up: np.ndarray, coarse: np.ndarray) -> float:
    """The share of photo pixels at a depth step whose depth is on none of the surfaces of the four samples
    around them (further than twice ``SURFACE_SPREAD`` from every one)."""
    h, w = up.shape
    dh, dw = coarse.shape
    y = np.minimum(((np.arange(h) + 0.5) * dh / h - 0.5).clip(0).astype(int), dh - 2)
    x = np.minimum(((np.arange(w) + 0.5) * dw / w - 0.5).clip(0).astype(int), dw - 2)
    samples = np.stack([coarse[y + dy][:, x + dx] for dy in (0, 1) for dx in (0, 1)])
    step = samples.max(axis=0) > samples.min(axis=0) * (1 + SURFACE_SPREAD)
    off_every_surface = (np.abs(up[None] - samples) > 2 * SURFACE_SPREAD * samples).all(axis=0)
    return float((step & off_every_surface).mean())


def test_the_real_iphone_depth_is_upsampled_without_depth_between_surfaces():
    rgb = np.asarray(Image.open(IPHONE / "image.jpg").convert("RGB"))
    coarse = np.asarray(Image.open(IPHONE / "arkit_depth.png"), dtype=np.float32) / 1000.0
    assert rgb.shape == (1440, 1920, 3) and coarse.shape == (192, 256)
    ours = upsample_depth(coarse, rgb)
    bilinear = np.asarray(Image.fromarray(coarse, mode="F").resize((1920, 1440), Image.BILINEAR))
    nearest = np.asarray(Image.fromarray(coarse, mode="F").resize((1920, 1440), Image.NEAREST))
    assert between_surfaces(ours, coarse) == 0 < between_surfaces(bilinear, coarse)
    # The project's edge score at half size (no intrinsics were published: any camera serves, depth and
    # photo share one view).
    k = Intrinsics(720.0, 720.0, 479.5, 359.5, 960, 720)
    same = ColourCamera(fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy)
    scores = {
        name: alignment([Frame(rgb[::2, ::2].copy(), depth[::2, ::2].copy(), k, name)], same)
        for name, depth in (("ours", ours), ("bilinear", bilinear), ("nearest", nearest))
    }
    print(f"\nedge score on the iPhone frame: {scores}")
    assert scores["ours"] >= scores["bilinear"] - 0.01 and scores["ours"] > scores["nearest"] + 0.05, scores


@pytest.mark.parametrize("frame_column", [True, False])
def test_a_written_export_reads_back_as_its_frames(tmp_path, frame_column):
    frames = mosd_frames(5)
    root = write_stray_scanner(tmp_path / "scan", frames, MOSD_CAMERA, odometry_frame_column=frame_column)
    assert detect_format(root) == "strayscanner"
    recording = open_recording(root, None, ReadOptions(), tmp_path / "run")
    assert [p.name for p in recording.pairs] == [f"{100 + i / 30:.6f}" for i in range(5)]
    assert recording.notes[0].startswith("stray scanner: 5 depth maps, video 640x480 written at 640x480")
    assert recording.notes[1] == "kept 5 of 5 frames: every frame"
    assert "confidence 2 and up kept" in recording.notes[2]
    first = recording.pairs[0]
    assert (first.camera.fx, first.camera.cx, first.depth_scale) == (525.0, 319.5, 1000.0)
    for pair, (rgb, mm) in zip(recording.pairs, frames, strict=True):
        photo = np.asarray(Image.open(pair.rgb).convert("RGB"), dtype=np.float32)
        assert np.abs(photo - rgb).mean() < 4  # H.264 at crf 12, then JPEG
        depth = np.asarray(Image.open(pair.depth), dtype=np.float32)
        assert not depth[:112, :152].any()  # confidence 1 over the top-left quarter: dropped
        both = (depth > 0) & (mm > 0)
        assert both.mean() > 0.3 and np.median(np.abs(depth[both] - mm[both])) < 10  # mm, from 256x192
    thinned = open_recording(root, None, ReadOptions(every=2), tmp_path / "thin")
    assert len(thinned.pairs) == 3 and thinned.notes[1] == "kept 3 of 5 frames: every 2th frame"


@pytest.mark.parametrize("kind", ["strayscanner", "record3d"])
def test_a_long_phone_export_keeps_an_evenly_spread_cap_and_writes_only_those(tmp_path, kind):
    frames = mosd_frames(9)
    if kind == "strayscanner":
        path = write_stray_scanner(tmp_path / "scan", frames, MOSD_CAMERA)
    else:
        path = write_record3d(tmp_path / "scan.r3d", frames, MOSD_CAMERA)
    recording = open_recording(path, None, ReadOptions(max_frames=3), tmp_path / "run")
    start = 100 if kind == "strayscanner" else 0  # odometry's timestamps, or frame numbers over the fps
    assert [p.name for p in recording.pairs] == [f"{start + i / 30:.6f}" for i in (0, 4, 8)]
    capped = "capped at 3 evenly spread (--max-frames 3; 0 keeps all)"
    assert recording.notes[1] == f"kept 3 of 9 frames: every frame, {capped}"
    written = sorted((tmp_path / "run" / f"{kind}-frames" / "color").iterdir())
    assert len(written) == 3  # the other six were never converted or written
    everything = open_recording(path, None, ReadOptions(max_frames=None), tmp_path / "all")
    assert len(everything.pairs) == 9


def test_exports_that_cannot_be_read_are_refused_in_one_line(tmp_path):
    root = write_stray_scanner(tmp_path / "scan", mosd_frames(2), MOSD_CAMERA)
    (root / "camera_matrix.csv").unlink()
    with pytest.raises(UserError, match=r"camera_matrix.csv: missing"):
        read_stray_scanner(root, tmp_path / "a")
    root = write_stray_scanner(tmp_path / "scan2", mosd_frames(2), MOSD_CAMERA)
    (root / "rgb.mp4").write_bytes(b"\0\0\0\x18ftypmp42" + b"\x13" * 500)
    with pytest.raises(
        UserError, match=r"rgb.mp4: no frame could be decoded \(rgb.mp4 is damaged: it cannot be decoded past frame 0"
    ):
        read_stray_scanner(root, tmp_path / "b")


@pytest.mark.slow
def test_fit_from_a_stray_scanner_export_publishes_a_model(registry, tmp_path):
    small = [(np.asarray(Image.fromarray(rgb).resize((160, 120), Image.BILINEAR)), mm) for rgb, mm in mosd_frames(24)]
    root = write_stray_scanner(tmp_path / "scan", small, MOSD_CAMERA.resized(160, 120))
    args = ["fit", str(root), "--name", "scan-room", "--licence", "mOSD (research use), test copy", "--budget", "1"]
    args += ["--from", str(registry / "tiny" / "0.1.0"), "--registry", str(tmp_path / "registry")]
    out = run_cli(*args, "--out", str(tmp_path / "run"), "--register", "no", cwd=REPO).stdout
    assert "(strayscanner)" in out and "stray scanner: 24 depth maps" in out and "| fitted model |" in out
    assert load_card(tmp_path / "registry" / "scan-room" / "0.1.0").training.data[0].format == "strayscanner"


def test_a_written_record3d_export_reads_back_as_its_frames(tmp_path):
    frames = mosd_frames(4)
    path = write_record3d(tmp_path / "room.r3d", frames, MOSD_CAMERA)
    assert detect_format(path) == "record3d"
    recording = open_recording(path, None, ReadOptions(), tmp_path / "run")
    assert [p.name for p in recording.pairs] == [f"{i / 30:.6f}" for i in range(4)]
    assert recording.notes[0] == "record3d: 4 frames, photos 640x480 written at 640x480, depth 256x192"
    assert (recording.pairs[0].camera.fx, recording.pairs[0].camera.cy) == (525.0, 239.5)
    for pair, (rgb, mm) in zip(recording.pairs, frames, strict=True):
        assert np.abs(np.asarray(Image.open(pair.rgb).convert("RGB"), dtype=np.float32) - rgb).mean() < 4
        depth = np.asarray(Image.open(pair.depth), dtype=np.float32)
        both = (depth > 0) & (mm > 0)
        assert both.mean() > 0.3 and np.median(np.abs(depth[both] - mm[both])) < 10


def test_a_damaged_record3d_export_is_refused_in_one_line(tmp_path):
    path = write_record3d(tmp_path / "room.r3d", mosd_frames(2), MOSD_CAMERA)
    truncated = tmp_path / "cut.r3d"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(UserError, match=r"cut.r3d: not a complete .r3d \(zip\) file"):
        read_record3d(truncated, tmp_path / "a")
    import zipfile

    with zipfile.ZipFile(path, "a") as archive:  # a depth map cut short inside an intact zip
        archive.writestr("rgbd/5.jpg", archive.read("rgbd/0.jpg"))
        archive.writestr("rgbd/5.depth", archive.read("rgbd/0.depth")[:100])
    with pytest.raises(UserError, match=r"room.r3d: (damaged: rgbd/5.depth|rgbd/5.depth holds \d+ values)"):
        read_record3d(path, tmp_path / "b")


def test_camera_overrides_reach_a_phone_export_in_its_own_pixels_before_frames_are_written(tmp_path):
    """--fx for a Stray Scanner video is in the video's pixels (1600x1200 here); frames are written at the 640x480
    fit trains at, so the written camera's fx is 0.4 of it. Record3D's K is overridden the same way."""
    frames = [
        (np.asarray(Image.fromarray(rgb).resize((1600, 1200), Image.BILINEAR)), depth) for rgb, depth in mosd_frames(2)
    ]
    big = MOSD_CAMERA.resized(1600, 1200)
    override = CameraFile(fx=1000.0, cx=800.0)
    root = write_stray_scanner(tmp_path / "scan", frames, big)
    recording = open_recording(root, None, ReadOptions(camera=override), tmp_path / "a")
    camera = recording.pairs[0].camera
    assert (camera.width, camera.fx, camera.fy) == (640, pytest.approx(400.0), pytest.approx(big.fy * 0.4))
    assert camera.cx == pytest.approx((800.0 + 0.5) * 0.4 - 0.5)
    path = write_record3d(tmp_path / "scan.r3d", frames, big)
    camera = open_recording(path, None, ReadOptions(camera=override), tmp_path / "b").pairs[0].camera
    assert (camera.width, camera.fx) == (640, pytest.approx(400.0))
