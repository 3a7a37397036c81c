"""Azure Kinect (and Orbbec Femto) recordings: the real sample, and files written in every colour and depth mode.

The real ``azure-kinect.mkv`` (pyk4a's test asset) holds one frame per track: it shows the layout and the
factory calibration, and its registered depth is checked against the photo's edges and, point by point,
against the calibration applied by hand. Files with many frames are written here with PyAV in the layout
``k4arecorder`` writes (``harness.kinect_recordings``), over a scene whose depth is known in closed form
(a tilted wall with a card in front of it), seen through the sample's real lenses.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import REPO
from PIL import Image

from contract.errors import UserError
from contract.geometry import ColourCamera, Intrinsics
from harness.kinect_recordings import write_kinect_recording
from recordings.azure_kinect import KinectOptions, read_kinect
from recordings.formats import ReadOptions, detect_format, open_recording
from recordings.frames import Frame
from recordings.kinect_calibration import COLOUR_RESOLUTIONS, DEPTH_MODES, depth_to_colour, mode_lens
from recordings.lens import Lens
from recordings.registration import alignment

CAPTURES = REPO.parent / "shared" / "data" / "captures"
SAMPLE = CAPTURES / "azure-kinect.mkv"
CALIBRATION = (CAPTURES / "azure-kinect-calibration.json").read_bytes()


def sample_calibration() -> dict:
    import av

    with av.open(str(SAMPLE)) as container:
        return json.loads(bytes(container.streams.attachments[0].data))


# --- the real recording ----------------------------------------------------------------------------------


def test_the_real_recording_is_read_and_its_depth_lines_up_with_the_photo(tmp_path):
    """What fit prints for the sample, and the registered depth's edges on the photo's: a shift of 3 px or more
    either way lines up worse, so the calibration, not luck, put the depth where it is."""
    assert detect_format(SAMPLE) == "azurekinect"
    recording = read_kinect(SAMPLE, tmp_path)
    assert [p.name for p in recording.pairs] == ["0.463945"] and recording.skipped == []
    notes = "\n".join(recording.notes)
    print("\n" + notes)
    assert "colour MJPG_720P (1 frames), depth NFOV_UNBINNED 640x576 (1 frames), depth unit 1 mm" in notes
    assert "IMU, IR tracks not used" in notes and "depth delay (0 ms)" in notes
    assert "translation (-32.1, -2.2, 3.9) mm, rotation 4.94 deg" in notes
    pair = recording.pairs[0]
    rgb = np.asarray(Image.open(pair.rgb).convert("RGB"))
    depth = np.asarray(Image.open(pair.depth)).astype(np.float32) / 1000
    assert rgb.shape[:2] == depth.shape == (416, 739) and 0.45 < (depth > 0).mean() < 0.55
    k = pair.camera
    same = ColourCamera(fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy)
    registered = alignment([Frame(rgb, depth, k, "0")], same)
    shifts = [(3, 0), (-3, 0), (0, 3), (0, -3), (6, 6), (-6, -6), (12, 0), (0, -12)]
    moved = {s: alignment([Frame(rgb, np.roll(depth, s[::-1], axis=(0, 1)), k, "0")], same) for s in shifts}
    print(f"edge score: registered {registered:.3f}, shifted at most {max(moved.values()):.3f}")
    assert all(registered > score for score in moved.values()), (registered, moved)


def test_a_depth_pixel_lands_where_the_calibration_by_hand_puts_it(tmp_path):
    """Each camera worked out from calibration.json with the SDK's NFOV_UNBINNED and 720P windows written out
    here, a raw depth pixel undistorted with OpenCV's point undistortion, moved by Rt, and projected: the
    reader's depth at that colour pixel is the point's depth, on every smooth surface sampled."""
    import av

    recording = read_kinect(SAMPLE, tmp_path)
    pair = recording.pairs[0]
    written = np.asarray(Image.open(pair.depth)).astype(np.float64) / 1000
    cameras = {c["Location"]: c for c in sample_calibration()["CalibrationInformation"]["Cameras"]}
    d, c = cameras["CALIBRATION_CameraLocationD0"], cameras["CALIBRATION_CameraLocationPV0"]
    dp, cp = d["Intrinsics"]["ModelParameters"], c["Intrinsics"]["ModelParameters"]
    # NFOV unbinned: 1024x1024 sensor, 640x576 window at (192, 180); 720P: 1280x960 binned, window at (0, 120).
    depth_k = np.array([[dp[2] * 1024, 0, dp[0] * 1024 - 192.5], [0, dp[3] * 1024, dp[1] * 1024 - 180.5], [0, 0, 1]])
    depth_d = np.array([dp[4], dp[5], dp[13], dp[12], dp[6], dp[7], dp[8], dp[9]])
    colour_720 = Intrinsics(cp[2] * 1280, cp[3] * 960, cp[0] * 1280 - 0.5, cp[1] * 960 - 120.5, 1280, 720)
    assert pair.camera == colour_720.resized(739, 416)
    rotation = np.asarray(c["Rt"]["Rotation"]).reshape(3, 3)
    translation = np.asarray(c["Rt"]["Translation"])
    with av.open(str(SAMPLE)) as container:
        raw = next(p for p in container.demux(container.streams.video[1]) if p.size).decode()[0].to_ndarray()
    rng = np.random.default_rng(0)
    smooth = raw > 0
    for axis in (0, 1):  # a pixel whose neighbours hold nearly its depth: a surface, not an edge
        smooth &= np.abs(np.diff(raw.astype(float), axis=axis, prepend=0)) < 0.01 * raw
        smooth &= np.abs(np.diff(raw.astype(float), axis=axis, append=0)) < 0.01 * raw
    rows, cols = np.nonzero(smooth)
    picks = rng.choice(len(rows), 400, replace=False)
    pixels = np.stack([cols[picks], rows[picks]], 1).astype(np.float64)
    rays = cv2.undistortPoints(pixels.reshape(-1, 1, 2), depth_k, depth_d).reshape(-1, 2)
    z = raw[rows[picks], cols[picks]] / 1000.0
    points = np.column_stack([rays * z[:, None], z]) @ rotation.T + translation
    k = pair.camera
    u = np.rint(k.fx * points[:, 0] / points[:, 2] + k.cx).astype(int)
    v = np.rint(k.fy * points[:, 1] / points[:, 2] + k.cy).astype(int)
    inside = (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
    found = written[v[inside], u[inside]]
    expected = points[inside, 2]
    hit = found > 0
    assert inside.sum() > 300 and hit.mean() > 0.9
    error = np.abs(found[hit] - expected[hit]) / expected[hit]
    print(f"{hit.sum()} points: median depth error {np.median(error):.2%}, within 2%: {np.mean(error < 0.02):.1%}")
    assert np.median(error) < 0.003 and np.mean(error < 0.02) > 0.95, (np.median(error), np.mean(error < 0.02))


# --- written recordings: every mode, over a scene known in closed form ---------------------------------


WALL = (np.array([0.15, -0.1, -1.0]) / np.linalg.norm([0.15, -0.1, -1.0]), -1.9)  # n . p = d, in the depth frame
CARD = (1.2, 0.25, 0.18)  # z, half width, half height: a card facing the depth camera


def cast(origin: np.ndarray, rays: np.ndarray, wall_shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Where rays (depth-camera frame, from ``origin``) meet the scene: the points, and which hit the card."""
    n, d = WALL
    t_wall = (d - wall_shift - origin @ n) / (rays @ n)
    t_card = (CARD[0] - origin[2]) / rays[:, 2]
    on_card = origin + t_card[:, None] * rays
    card = (np.abs(on_card[:, 0]) < CARD[1]) & (np.abs(on_card[:, 1]) < CARD[2]) & (t_card < t_wall)
    t = np.where(card, t_card, t_wall)
    return origin + t[:, None] * rays, card


def pixel_rays(lens: Lens) -> np.ndarray:
    """Each pixel's ray (normalised, z = 1) through the lens, distortion and all, in the camera's frame."""
    k = lens.camera
    v, u = np.mgrid[0 : k.height, 0 : k.width]
    matrix = np.array([[k.fx, 0, k.cx], [0, k.fy, k.cy], [0, 0, 1]])
    pixels = np.stack([u.ravel(), v.ravel()], 1).astype(np.float64).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(pixels, matrix, np.asarray(lens.coefficients)).reshape(-1, 2)
    return np.column_stack([xy, np.ones(len(xy))])


def texture(points: np.ndarray, card: np.ndarray) -> np.ndarray:
    """A 5 cm checkerboard on the wall, a red card."""
    checker = ((np.floor(points[:, 0] / 0.05) + np.floor(points[:, 1] / 0.05)) % 2).astype(np.uint8)
    rgb = np.stack([60 + 150 * checker, 60 + 150 * checker, 80 + 120 * checker], 1)
    rgb[card] = (200, 40, 30)
    return rgb.astype(np.uint8)


def scene_recording(path: Path, colour_mode: str, depth_mode: str, frames: int, **options) -> tuple[Path, dict]:
    """A recording of the scene (the wall moving back 1 cm a frame) through the sample's lenses in these modes."""
    calibration = sample_calibration()["CalibrationInformation"]
    resolution = colour_mode.partition("_")[2]
    depth_lens = mode_lens(path, calibration, "depth", DEPTH_MODES[depth_mode])
    colour_lens = mode_lens(path, calibration, "colour", COLOUR_RESOLUTIONS[resolution])
    rotation, translation = depth_to_colour(path, calibration)
    depth_rays, colour_rays = pixel_rays(depth_lens), pixel_rays(colour_lens) @ rotation  # into the depth frame
    origin = -rotation.T @ translation
    radius = np.hypot(depth_rays[:, 0], depth_rays[:, 1]) <= depth_lens.max_radius
    photos, depths = [], []
    for i in range(frames):
        points, card = cast(origin, colour_rays, 0.01 * i)
        photos.append(texture(points, card).reshape(colour_lens.camera.height, colour_lens.camera.width, 3))
        points, _ = cast(np.zeros(3), depth_rays, 0.01 * i)
        mm = np.where(radius, np.rint(points[:, 2] * 1000), 0).astype(np.uint16)
        depths.append(mm.reshape(depth_lens.camera.height, depth_lens.camera.width))
    write_kinect_recording(path, photos, depths, colour_mode, depth_mode, CALIBRATION, **options)
    return path, {"rotation": rotation, "translation": translation, "origin": origin}


def expected_depth(camera: Intrinsics, geometry: dict, wall_shift: float) -> np.ndarray:
    """The scene's depth as a pinhole colour camera of ``camera`` sees it (what registration must give)."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    rays = np.column_stack([((u - camera.cx) / camera.fx).ravel(), ((v - camera.cy) / camera.fy).ravel()])
    rays = np.column_stack([rays, np.ones(len(rays))]) @ geometry["rotation"]
    points, _ = cast(geometry["origin"], rays, wall_shift)
    colour = points @ geometry["rotation"].T + geometry["translation"]
    return colour[:, 2].reshape(camera.height, camera.width)


MODES = [("MJPG_720P", mode) for mode in DEPTH_MODES] + [
    (f"{fmt}_720P", "NFOV_2X2BINNED") for fmt in ("NV12", "YUY2", "BGRA")
]


@pytest.mark.parametrize("colour_mode,depth_mode", MODES)
def test_each_colour_and_depth_mode_registers_to_the_scene_as_it_is(tmp_path, colour_mode, depth_mode):
    """Registered depth is the scene's depth in the colour camera (within 1% on 98% of the pixels away from
    the card's edge), and the photo is the scene through the undistorted colour camera."""
    path, geometry = scene_recording(tmp_path / "rec.mkv", colour_mode, depth_mode, 2)
    recording = open_recording(path, None, ReadOptions(), tmp_path / "scratch")
    assert recording.format == "azurekinect" and len(recording.pairs) == 2
    assert f"colour {colour_mode} (2 frames), depth {depth_mode}" in recording.notes[0]
    for i, pair in enumerate(recording.pairs):
        found = np.asarray(Image.open(pair.depth)).astype(np.float64) / 1000
        truth = expected_depth(pair.camera, geometry, 0.01 * i)
        step = np.hypot(*np.gradient(truth)) > 0.01
        away = ~cv2.dilate(step.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool) & (found > 0)
        error = np.abs(found[away] - truth[away]) / truth[away]
        assert away.mean() > 0.3 and np.mean(error < 0.01) > 0.98, (away.mean(), np.mean(error < 0.01))
    points, card = cast(geometry["origin"], _pinhole_rays(pair.camera) @ geometry["rotation"], 0.01)
    rendered = texture(points, card).reshape(pair.camera.height, pair.camera.width, 3).astype(float)
    photo = np.asarray(Image.open(pair.rgb).convert("RGB")).astype(float)
    inner = (slice(20, -20), slice(20, -20))  # the undistorted photo's border is empty where the lens saw less
    assert np.corrcoef(photo[inner].ravel(), rendered[inner].ravel())[0, 1] > 0.85


def _pinhole_rays(camera: Intrinsics) -> np.ndarray:
    v, u = np.mgrid[0 : camera.height, 0 : camera.width]
    xy = np.column_stack([((u - camera.cx) / camera.fx).ravel(), ((v - camera.cy) / camera.fy).ravel()])
    return np.column_stack([xy, np.ones(len(xy))])


def test_the_mode_cameras_agree_with_each_other_as_the_sensor_is_binned_and_cropped():
    """Binning halves a camera (pixel-centre rule); NFOV is WFOV's window at (192, 180); 720P is 1080P scaled."""
    calibration = sample_calibration()["CalibrationInformation"]
    here = Path("calibration.json")
    cams = {mode: mode_lens(here, calibration, "depth", DEPTH_MODES[mode]).camera for mode in DEPTH_MODES}
    assert cams["NFOV_UNBINNED"].resized(320, 288) == pytest.approx(cams["NFOV_2X2BINNED"])
    assert cams["WFOV_UNBINNED"].resized(512, 512) == pytest.approx(cams["WFOV_2X2BINNED"])
    wide, narrow = cams["WFOV_UNBINNED"], cams["NFOV_UNBINNED"]
    assert (narrow.fx, narrow.cx, narrow.cy) == pytest.approx((wide.fx, wide.cx - 192, wide.cy - 180))
    colour = {r: mode_lens(here, calibration, "colour", COLOUR_RESOLUTIONS[r]).camera for r in ("720P", "1080P")}
    assert colour["1080P"].resized(1280, 720) == pytest.approx(colour["720P"])


def test_the_depth_delay_pairs_depth_taken_later(tmp_path):
    """Depth stamped 15 ms after colour (``--depth-delay 15000``) pairs at a 0 ms gap, and a recording whose
    depth is 15 ms late without saying so is refused with the gap and the option that allows it."""
    path, _ = scene_recording(tmp_path / "rec.mkv", "MJPG_720P", "NFOV_2X2BINNED", 3, depth_delay_ns=15_000_000)
    recording = read_kinect(path, tmp_path / "a", KinectOptions(max_gap_s=0.005))
    assert len(recording.pairs) == 3 and "depth delay (15 ms): 3 of 3 colour frames, gap median 0.0 ms" in "\n".join(
        recording.notes
    )
    data = path.read_bytes().replace(b"15000000", b"00000000")  # the tag says no delay; the stamps still differ
    path.write_bytes(data)
    with pytest.raises(UserError, match=r"no colour frame has depth within 5 ms .* pass --max-gap-ms"):
        read_kinect(path, tmp_path / "b", KinectOptions(max_gap_s=0.005))


def test_a_long_recording_keeps_an_evenly_spread_cap(tmp_path):
    path, _ = scene_recording(tmp_path / "rec.mkv", "MJPG_720P", "NFOV_2X2BINNED", 9)
    recording = read_kinect(path, tmp_path / "out", KinectOptions(max_frames=3))
    assert [p.name for p in recording.pairs] == [f"{0.2 + round(i * 1000 / 30) / 1000:.6f}" for i in (0, 4, 8)]
    assert "kept 3 of 9 frames: every frame, capped at 3 evenly spread" in "\n".join(recording.notes)


# --- broken recordings: one line that names the file --------------------------------------------------------


def refused(path: Path, tmp_path: Path, **options) -> str:
    with pytest.raises(UserError) as error:
        read_kinect(path, tmp_path / "out", KinectOptions(**options))
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{path}: ")
    return message


def tiny(path: Path, depth_mode: str = "NFOV_2X2BINNED", calibration: bytes | None = CALIBRATION, frames: int = 2):
    photos = [np.full((720, 1280, 3), 90 + i, np.uint8) for i in range(frames)]
    size = DEPTH_MODES.get(depth_mode, DEPTH_MODES["WFOV_UNBINNED"]).size
    depths = [np.full(size[::-1], 1500, np.uint16) for _ in range(frames)]
    return write_kinect_recording(path, photos, depths, "MJPG_720P", depth_mode, calibration)


def test_passive_ir_is_refused_with_the_mode_named(tmp_path):
    message = refused(tiny(tmp_path / "ir.mkv", "PASSIVE_IR"), tmp_path)
    assert "depth mode PASSIVE_IR records infrared only, no depth" in message


def test_a_recording_without_its_calibration_is_refused(tmp_path):
    assert "no calibration.json attachment" in refused(tiny(tmp_path / "c.mkv", calibration=None), tmp_path)
    broken = tiny(tmp_path / "j.mkv", calibration=b"{not json")
    assert "its calibration.json is not an Azure Kinect calibration" in refused(broken, tmp_path)


def test_a_recording_without_a_depth_track_is_refused(tmp_path):
    path = tiny(tmp_path / "d.mkv")
    path.write_bytes(path.read_bytes().replace(b"DEPTH", b"OTHER"))  # the track's name, as a colour-only recording
    assert "no DEPTH track" in refused(path, tmp_path)


def test_a_truncated_recording_is_refused_or_read_to_where_it_ends(tmp_path):
    """Cut in its header: refused in one line. Cut after some frames: those frames are read, the rest named."""
    path = tiny(tmp_path / "t.mkv", frames=6)
    data = path.read_bytes()
    (tmp_path / "head.mkv").write_bytes(data[:300])
    assert refused(tmp_path / "head.mkv", tmp_path)
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(data[: len(data) * 2 // 3])
    recording = read_kinect(cut, tmp_path / "cut")
    assert 1 <= len(recording.pairs) < 6


def test_a_damaged_frame_among_many_is_skipped_and_named(tmp_path):
    path = tiny(tmp_path / "f.mkv", frames=4)
    data = bytearray(path.read_bytes())
    second_jpeg = data.find(b"\xff\xd8", data.find(b"\xff\xd8") + 2)
    data[second_jpeg : second_jpeg + 600] = bytes(600)  # the second photo's JPEG header and tables wiped
    path.write_bytes(bytes(data))
    recording = read_kinect(path, tmp_path / "out")
    assert len(recording.pairs) == 3
    assert [name for name, _ in recording.skipped] == ["0.233000"]
    assert "colour frame damaged" in recording.skipped[0][1]


def test_a_depth_scale_for_a_kinect_recording_is_refused(tmp_path):
    from recordings.folders import CameraFile

    with pytest.raises(UserError, match="--depth-scale does not apply to a azurekinect recording"):
        open_recording(tiny(tmp_path / "s.mkv"), None, ReadOptions(camera=CameraFile(depth_scale=1000)), tmp_path)


# --- fit, end to end ------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_fit_reads_a_kinect_recording_end_to_end(tmp_path, registry):
    """A 24-frame recording written as k4arecorder would: fit reads, trains, scores and publishes it."""
    path, _ = scene_recording(tmp_path / "room.mkv", "MJPG_720P", "NFOV_2X2BINNED", 24)
    args = [
        "fit", str(path), "--name", "kinect-room", "--licence", "test scene", "--budget", "1",
        "--from", str(registry / "tiny" / "0.1.0"), "--registry", str(tmp_path / "registry"),
        "--out", str(tmp_path / "run"), "--register", "no",
    ]  # fmt: skip
    result = subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "Azure Kinect recording: colour MJPG_720P (24 frames), depth NFOV_2X2BINNED" in result.stdout
    assert "pairs: 24 found, 0 skipped" in result.stdout and "| fitted model |" in result.stdout
    assert (tmp_path / "registry" / "kinect-room" / "0.1.0" / "card.json").is_file()


# --- each mode's camera against the Sensor SDK's windows and formulas, worked by hand ------------------------


def hand_calibration(colour_sensor: tuple[int, int], colour_params: list[float]) -> dict:
    """A calibration.json of round numbers: depth (cx, cy, fx, fy) = (0.5, 0.49, 0.49, 0.5) of its 1024x1024
    sensor, k1-k6 = 0.1-0.6, p2 0.007, p1 0.003; the depth camera turned 90 degrees about z and 1 cm along x
    from the device frame; colour 3.2 cm along -x with no turn."""
    depth = [0.5, 0.49, 0.49, 0.5, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.0, 0.0, 0.007, 0.003]
    model = "CALIBRATION_LensDistortionModelBrownConrady"

    def camera(location: str, size: tuple[int, int], params: list[float], rotation: list, translation: list) -> dict:
        return {
            "Location": location,
            "Purpose": "",
            "SensorWidth": size[0],
            "SensorHeight": size[1],
            "MetricRadius": 1.7,
            "Intrinsics": {"ModelType": model, "ModelParameterCount": 14, "ModelParameters": params},
            "Rt": {"Rotation": rotation, "Translation": translation},
        }

    quarter = [0, -1, 0, 1, 0, 0, 0, 0, 1]
    return {
        "Cameras": [
            camera("CALIBRATION_CameraLocationD0", (1024, 1024), depth, quarter, [0.01, 0, 0]),
            camera(
                "CALIBRATION_CameraLocationPV0",
                colour_sensor,
                colour_params,
                [1, 0, 0, 0, 1, 0, 0, 0, 1],
                [-0.032, 0, 0],
            ),
        ]
    }


def fields(k: Intrinsics) -> tuple[float, ...]:
    return (k.fx, k.fy, k.cx, k.cy, k.width, k.height)


#: Per depth mode, the SDK's window (binned sensor, crop offset, size), and the camera it gives, by hand:
#: f = f_norm * binned, c = c_norm * binned - offset - 0.5 (the calibration's 0 is a pixel's corner).
DEPTH_BY_HAND = {
    "NFOV_UNBINNED": (501.76, 512.0, 512 - 192 - 0.5, 501.76 - 180 - 0.5, 640, 576),
    "NFOV_2X2BINNED": (250.88, 256.0, 256 - 96 - 0.5, 250.88 - 90 - 0.5, 320, 288),
    "WFOV_UNBINNED": (501.76, 512.0, 511.5, 501.26, 1024, 1024),
    "WFOV_2X2BINNED": (250.88, 256.0, 255.5, 250.38, 512, 512),
}


#: A 4:3 colour calibration (cx, cy, fx, fy) = (0.5, 0.5, 0.48, 0.62): per resolution, by hand, from the SDK's
#: windows (binned sensor, then the rows cut from it): f = f_norm * binned, c = c_norm * binned - offset - 0.5.
COLOUR_BY_HAND = {
    "720P": (614.4, 595.2, 639.5, 480 - 120 - 0.5, 1280, 720),
    "1080P": (921.6, 892.8, 959.5, 720 - 180 - 0.5, 1920, 1080),
    "1440P": (1228.8, 1190.4, 1279.5, 960 - 240 - 0.5, 2560, 1440),
    "1536P": (983.04, 952.32, 1023.5, 767.5, 2048, 1536),
    "2160P": (1843.2, 1785.6, 1919.5, 1440 - 360 - 0.5, 3840, 2160),
    "3072P": (1966.08, 1904.64, 2047.5, 1535.5, 4096, 3072),
}


MODES_BY_HAND = [("depth", DEPTH_MODES[m], m, k) for m, k in DEPTH_BY_HAND.items()] + [
    ("colour", COLOUR_RESOLUTIONS[r], r, k) for r, k in COLOUR_BY_HAND.items()
]


@pytest.mark.parametrize(("which", "mode", "name", "expected"), MODES_BY_HAND, ids=[m[2] for m in MODES_BY_HAND])
def test_each_mode_s_camera_is_the_sdk_s_worked_by_hand(which, mode, name, expected):
    """Depth (cx, cy, fx, fy) = (0.5, 0.49, 0.49, 0.5), colour (0.5, 0.5, 0.48, 0.62), in every mode."""
    calibration = hand_calibration((4096, 3072), [0.5, 0.5, 0.48, 0.62] + [0.0] * 10)
    lens = mode_lens(Path("hand.mkv"), calibration, which, mode)
    assert fields(lens.camera) == pytest.approx(expected)
    if which == "depth":  # OpenCV's order is k1, k2, p1, p2, k3, k4, k5, k6; the calibration's ends p2, p1
        assert lens.coefficients == pytest.approx((0.1, 0.2, 0.003, 0.007, 0.3, 0.4, 0.5, 0.6))


def test_a_lens_s_p1_bends_a_point_as_brown_conrady_says():
    """Only p1 set (0.01, the calibration's last parameter): a ray at (0.1, 0.2) lands at x + 2 p1 x y =
    0.1004, y + p1 (r^2 + 2 y^2) = 0.2013 through the lens as OpenCV applies it."""
    params = [0.5, 0.5, 0.48, 0.64] + [0.0] * 9 + [0.01]
    lens = mode_lens(Path("hand.mkv"), hand_calibration((4096, 3072), params), "colour", COLOUR_RESOLUTIONS["3072P"])
    k = lens.camera
    matrix = np.array([[k.fx, 0, k.cx], [0, k.fy, k.cy], [0, 0, 1]])
    pixel, _ = cv2.projectPoints(
        np.array([[0.1, 0.2, 1.0]]), np.zeros(3), np.zeros(3), matrix, np.array(lens.coefficients)
    )
    u, v = pixel.ravel()
    assert ((u - k.cx) / k.fx, (v - k.cy) / k.fy) == pytest.approx((0.1004, 0.2013), abs=1e-9)


def test_a_16_9_colour_calibration_is_moved_onto_4_3_first_as_the_sdk_does():
    """A 3840x2160 calibration (cx, cy, fx, fy) = (0.5, 0.45, 0.45, 0.8): the SDK puts it on the 4:3 sensor
    (2880 rows) first: cy = (0.45 x 2160 + (2880 - 2160) / 2) / 2880 = 0.4625, fy = 0.8 x 2160 / 2880 = 0.6.
    At 720P (1280x960 binned, rows 120 on): fy = 576, cy = 444 - 120 - 0.5 = 323.5; fx = 576, cx = 639.5."""
    calibration = hand_calibration((3840, 2160), [0.5, 0.45, 0.45, 0.8] + [0.0] * 10)
    lens = mode_lens(Path("hand.mkv"), calibration, "colour", COLOUR_RESOLUTIONS["720P"])
    assert fields(lens.camera) == pytest.approx((576.0, 576.0, 639.5, 323.5, 1280, 720))


def test_depth_to_colour_composes_the_two_poses_in_the_sdk_s_direction():
    """Each camera's Rt takes device-frame points into that camera. The device point (0, 0, 1) is (0.01, 0, 1)
    in the depth camera (a quarter turn about z leaves the axis alone, then 1 cm along x), and (-0.032, 0, 1) in
    the colour camera: depth to colour must take the one to the other. And the quarter turn takes the device's
    -y axis to the depth camera's x: so the depth camera's x is the colour camera's -y."""
    rotation, translation = depth_to_colour(Path("hand.mkv"), hand_calibration((4096, 3072), [0.5] * 4 + [0.0] * 10))
    assert rotation @ np.array([0.01, 0.0, 1.0]) + translation == pytest.approx([-0.032, 0.0, 1.0])
    assert rotation @ np.array([1.0, 0.0, 0.0]) == pytest.approx([0.0, -1.0, 0.0])
