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
Each kept frame is written at the size fit trains at, by the writer both phone readers share
(``recordings.pair_writer``); of a long recording, an evenly spread cap of frames is kept.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image

from contract.errors import UserError
from contract.geometry import Intrinsics
from recordings.folders import CameraFile
from recordings.frames import PairsReader
from recordings.pair_writer import PairWriter, written_pairs
from recordings.phone_options import PhoneOptions

if TYPE_CHECKING:
    import av


def is_stray_scanner(root: Path) -> bool:
    """A Stray Scanner export: depth/ beside rgb.mp4, or beside the app's own camera_matrix.csv (so an export
    whose video is missing is named as such, not as a folder of unknown layout)."""
    root = Path(root)
    has_video = (root / "rgb.mp4").is_file() or (root / "camera_matrix.csv").is_file()
    return root.is_dir() and has_video and (root / "depth").is_dir()


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


def read_stray_scanner(root: Path, out: Path, options: PhoneOptions | None = None) -> PairsReader:
    """The kept frames with depth, written under ``out`` as colour JPEG and 16-bit millimetre PNG.

    Only the kept frames are converted and written, and decoding stops after the last of them.
    """
    root, out, options = Path(root), Path(out), options or PhoneOptions()
    if not (root / "rgb.mp4").is_file():
        raise UserError(f"{root / 'rgb.mp4'}: missing; a Stray Scanner export holds its colour video there")
    matrix = read_camera_matrix(root / "camera_matrix.csv")
    times = read_frame_times(root / "odometry.csv")
    depths = {int(p.stem): p for p in (root / "depth").glob("*.png") if p.stem.isdigit()}
    if not depths:
        raise UserError(f"{root / 'depth'}: no NNNNNN.png depth maps")
    wanted = options.kept(sorted(depths))
    pairs, writer, kept_share, decoded = [], None, [], set()
    video = _Video(root / "rgb.mp4")
    for number, frame in video.frames(set(wanted)):
        decoded.add(number)
        if writer is None:
            writer = PairWriter(out, frame.width, frame.height)
            recorded = _camera(matrix, frame.width, frame.height)
            video_camera = CameraFile.of(recorded).merged(options.camera).intrinsics(frame.width, frame.height, root)
        metres, share = _depth(root, number, options.min_confidence)
        kept_share.append(share)
        name = f"{times[number]:.6f}" if number in times else f"{number:06d}"
        pairs.append(writer.write(name, frame.to_image(), metres))
    if writer is None:
        raise UserError(f"{root / 'rgb.mp4'}: no frame could be decoded{video.why}")
    missing = "the video has no frame with this number" + video.why
    skipped = [(f"{n:06d}", missing) for n in wanted if n not in decoded]
    camera = writer.camera(video_camera)
    notes = [
        f"stray scanner: {len(depths)} depth maps, video {video_camera.width}x{video_camera.height} written at "
        f"{camera.width}x{camera.height}",
        options.note(len(depths), len(wanted)),
        f"depth: confidence {options.min_confidence} and up kept, {100 * float(np.mean(kept_share)):.0f}% of depth "
        f"pixels; upsampled from {metres.shape[1]}x{metres.shape[0]} without blending across depth steps",
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


class _Video:
    """The colour video's frames in order, decoded with PyAV; where it ends early, ``why`` says so."""

    def __init__(self, path: Path):
        self.path = path
        self.why = ""

    def frames(self, wanted: set[int]) -> Iterator[tuple[int, av.VideoFrame]]:
        """(frame number, decoded frame) for each wanted frame, in order; stops after the last wanted one.

        Frames are decoded on FFmpeg's threads, and only wanted ones are converted to pixels. A video cut
        short or damaged part-way gives the frames before the damage, and ``why`` names the file and the
        frame it ended at, for the skipped frames' reason.
        """
        import av

        number = -1
        last = max(wanted)
        try:
            with av.open(str(self.path)) as container:
                stream = container.streams.video[0]
                stream.thread_type = "AUTO"
                for number, frame in enumerate(container.decode(stream)):
                    if number in wanted:
                        yield number, frame
                    if number >= last:
                        return
        except (av.error.FFmpegError, IndexError):
            self.why = f" ({self.path.name} is damaged: it cannot be decoded past frame {number + 1})"
            return
        self.why = f" ({self.path.name} ends after {number + 1} frames: cut short?)"
