"""Stray Scanner recordings (iPhone and iPad LiDAR) as colour/depth pairs in the colour camera, written out.

A Stray Scanner export is a folder (the app's format document, strayrobots/scanner docs/format.md):

- ``rgb.mp4``: the colour video (1920x1440 on current phones), one frame per depth map;
- ``depth/NNNNNN.png``: 256x192 16-bit millimetres, over the same view as the video;
- ``confidence/NNNNNN.png``: 0, 1 or 2 per depth pixel; only ``min_confidence`` and up is kept;
- ``camera_matrix.csv``: the 3x3 intrinsics of the video's frames;
- ``odometry.csv``: a pose per frame, with a header; the app has written it with and without a
  ``frame`` column. Only its timestamps are used here, to name the frames.

The video is decoded with PyAV: it gives every frame in order from FFmpeg's decoders (the app
writes HEVC) without OpenCV's GUI and image-processing weight, and the wheel carries FFmpeg.
Each kept frame is written at most 1280x960 (the video is larger than anything fit trains at),
and its depth is upsampled to it by ``trainer.registration.upsample_depth``: smooth within a
surface, and no depth invented across a step.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from PIL import Image

from contract.errors import UserError
from contract.geometry import Intrinsics
from trainer.data.frames import PairsReader, written_pairs
from trainer.registration import upsample_depth

#: Frames are written at most this many pixels: more than fit trains at (640x480), less than the video.
MAX_WRITTEN_PIXELS = 1280 * 960
#: Depth pixels of lower confidence are dropped by default: ARKit's 2 is "high".
DEFAULT_MIN_CONFIDENCE = 2


def is_stray_scanner(root: Path) -> bool:
    root = Path(root)
    return root.is_dir() and (root / "rgb.mp4").is_file() and (root / "depth").is_dir()


def read_camera_matrix(path: Path) -> np.ndarray:
    if not path.is_file():
        raise UserError(f"{path}: missing; a Stray Scanner export holds the camera's 3x3 intrinsics there")
    try:
        rows = [[float(v) for v in line.split(",")] for line in path.read_text().split("\n") if line.strip()]
        matrix = np.asarray(rows, dtype=np.float64)
    except ValueError as e:
        raise UserError(f"{path}: not a 3x3 matrix of numbers: {e}") from None
    if matrix.shape != (3, 3):
        raise UserError(f"{path}: expected 3 rows of 3 numbers, got shape {matrix.shape}")
    return matrix


def read_frame_times(path: Path) -> dict[int, float]:
    """Frame number -> timestamp from ``odometry.csv``, with or without its ``frame`` column; {} when absent."""
    if not path.is_file():
        return {}
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f, skipinitialspace=True))
    times = {}
    for number, row in enumerate(rows):
        try:
            frame = int(row["frame"]) if row.get("frame") not in (None, "") else number
            times[frame] = float(row["timestamp"])
        except (KeyError, ValueError) as e:
            raise UserError(f"{path}:{number + 2}: expected timestamp (and frame) columns: {e}") from None
    return times


def read_stray_scanner(
    root: Path, out: Path, every: int = 1, min_confidence: int = DEFAULT_MIN_CONFIDENCE
) -> PairsReader:
    """Every ``every``-th frame with depth, written under ``out`` as colour JPEG and 16-bit millimetre PNG."""
    root, out = Path(root), Path(out)
    matrix = read_camera_matrix(root / "camera_matrix.csv")
    times = read_frame_times(root / "odometry.csv")
    depths = {int(p.stem): p for p in (root / "depth").glob("*.png") if p.stem.isdigit()}
    if not depths:
        raise UserError(f"{root / 'depth'}: no NNNNNN.png depth maps")
    wanted = sorted(depths)[:: max(1, every)]
    (out / "color").mkdir(parents=True, exist_ok=True)
    (out / "depth").mkdir(parents=True, exist_ok=True)
    pairs, camera, kept_share, decoded = [], None, [], set()
    for number, rgb in _frames(root / "rgb.mp4", set(wanted)):
        decoded.add(number)
        video_camera = _camera(matrix, rgb.shape[1], rgb.shape[0])
        scale = min(1.0, float(np.sqrt(MAX_WRITTEN_PIXELS / (rgb.shape[0] * rgb.shape[1]))))
        size = (round(rgb.shape[1] * scale), round(rgb.shape[0] * scale))
        camera = video_camera.resized(*size)
        photo = np.asarray(Image.fromarray(rgb).resize(size, Image.BILINEAR)) if scale < 1 else rgb
        metres, share = _depth(root, number, min_confidence)
        kept_share.append(share)
        millimetres = np.clip(np.rint(upsample_depth(metres, photo) * 1000.0), 0, 65535).astype(np.uint16)
        name = f"{times[number]:.6f}" if number in times else f"{number:06d}"
        Image.fromarray(photo).save(out / "color" / f"{name}.jpg", quality=95)
        Image.fromarray(millimetres).save(out / "depth" / f"{name}.png")
        pairs.append((name, out / "color" / f"{name}.jpg", out / "depth" / f"{name}.png"))
    if camera is None:
        raise UserError(f"{root / 'rgb.mp4'}: no frame could be decoded")
    skipped = [(f"{n:06d}", "the video has no frame with this number") for n in wanted if n not in decoded]
    notes = [
        f"stray scanner: {len(depths)} depth maps, video {rgb.shape[1]}x{rgb.shape[0]} written at "
        f"{camera.width}x{camera.height}" + (f", every {every}th frame" if every > 1 else ""),
        f"depth: confidence {min_confidence} and up kept, {100 * float(np.mean(kept_share)):.0f}% of depth pixels; "
        f"upsampled from {metres.shape[1]}x{metres.shape[0]} without blending across depth steps",
    ]
    return written_pairs(root.name, pairs, camera, skipped, notes)


def _camera(matrix: np.ndarray, width: int, height: int) -> Intrinsics:
    return Intrinsics(matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], width, height)


def _depth(root: Path, number: int, min_confidence: int) -> tuple[np.ndarray, float]:
    """Frame ``number``'s depth in metres with low-confidence pixels dropped, and the share kept."""
    path = root / "depth" / f"{number:06d}.png"
    with Image.open(path) as im:
        depth = np.asarray(im, dtype=np.float32) / 1000.0
    confidence_path = root / "confidence" / f"{number:06d}.png"
    if confidence_path.is_file():
        with Image.open(confidence_path) as im:
            confidence = np.asarray(im)
        if confidence.shape != depth.shape:
            raise UserError(f"{confidence_path}: {confidence.shape}, but its depth map is {depth.shape}")
        depth = np.where(confidence >= min_confidence, depth, 0).astype(np.float32)
    return depth, float((depth > 0).mean())


def _frames(video: Path, wanted: set[int]):
    """(frame number, HxWx3 uint8) for each wanted frame of the video, in order."""
    import av

    try:
        with av.open(str(video)) as container:
            stream = container.streams.video[0]
            for number, frame in enumerate(container.decode(stream)):
                if number in wanted:
                    yield number, frame.to_ndarray(format="rgb24")
                if number >= max(wanted):
                    return
    except (av.error.FFmpegError, IndexError) as e:
        raise UserError(f"{video}: cannot decode the video: {e}") from None
