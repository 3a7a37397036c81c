"""What ``rgb2cloud stream`` sends: the frames of a webcam, a video, a folder of photos or any recording.

Each source yields ``SourceFrame``s in order, each an encoded photo with its time and, where the source
knows them, its camera, its colour frame's name and the sensor's own depth registered to the photo. A
recording is read exactly as ``fit`` reads it (``recordings.formats``): its colour frames with their
recorded stamps and camera, and its depth moved into the colour camera.
"""

from __future__ import annotations

import io
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from contract.errors import UserError
from contract.geometry import Intrinsics
from recordings.formats import WRITTEN, ReadOptions, detect_format, open_recording
from recordings.frames import read_depth_png

PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp", ".bmp", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".webm", ".m4v", ".mkv")
#: The frame every message of a source without a named colour frame is in (realsense-ros's name).
DEFAULT_FRAME_ID = "camera_color_optical_frame"
JPEG_QUALITY = 90


@dataclass
class SourceFrame:
    """One frame to send: its name (for output files), time in nanoseconds, and the encoded photo."""

    name: str
    stamp_ns: int
    data: bytes
    #: The photo's camera where the source records one (sent as fx, fy, cx, cy), else None.
    camera: Intrinsics | None = None
    #: The sensor's depth in metres registered to the photo, where the source has a depth sensor.
    sensor_depth: Path | None = None
    depth_scale: float = 1000.0

    def sensor_metres(self) -> np.ndarray | None:
        return None if self.sensor_depth is None else read_depth_png(self.sensor_depth, self.depth_scale)


@dataclass
class Source:
    """A source's frames, whether it is live (keep only the freshest) and the colour frame it names."""

    frames: Iterator[SourceFrame]
    live: bool
    frame_id: str = DEFAULT_FRAME_ID
    description: str = ""
    #: Whether the frames' sensor depth is registered to the photo (bags, Kinect and phone recordings are
    #: read so; folders, TUM and 7-Scenes hold their depth as the sensor took it).
    registered: bool = False
    #: Whether each frame carries the camera a recording gives it (``SourceFrame.camera``), which the
    #: reader applies ``ReadOptions.camera`` to; a camera's, video's or photos' frames carry none.
    recorded_camera: bool = False


def wall_ns() -> int:
    return time.time_ns()


def jpeg(rgb: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="JPEG", quality=JPEG_QUALITY)
    return buffer.getvalue()


def _numeric_key(path: Path) -> tuple:
    """``frame-2`` before ``frame-10``: digits compare as numbers."""
    return tuple(int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name))


def photo_folder(root: Path) -> Source:
    """A folder's photos in numeric order, stamped with the wall clock as they are read."""
    photos = sorted((p for p in root.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES), key=_numeric_key)
    if not photos:
        raise UserError(f"{root}: no photos ({', '.join(PHOTO_SUFFIXES)})")
    frames = (SourceFrame(p.stem, wall_ns(), p.read_bytes()) for p in photos)
    return Source(frames, live=False, description=f"{len(photos)} photos")


def video(path: Path) -> Source:
    """A video file's frames (PyAV), each stamped with its presentation time."""
    import av

    try:
        container = av.open(str(path))
    except av.error.FFmpegError as e:
        raise UserError(f"{path}: not a video FFmpeg can read: {e}") from None
    stream = container.streams.video[0]

    def frames() -> Iterator[SourceFrame]:
        with container:
            for index, frame in enumerate(container.decode(stream)):
                seconds = float(frame.pts * frame.time_base) if frame.pts is not None else index / 30.0
                yield SourceFrame(f"{index:06d}", round(seconds * 1e9), jpeg(frame.to_ndarray(format="rgb24")))

    return Source(frames(), live=False, description=f"video, {stream.frames or 'unknown'} frames")


def webcam(device: str) -> Source:
    """A camera through OpenCV (``/dev/videoN`` or an index), stamped with the wall clock as captured."""
    import cv2

    capture = cv2.VideoCapture(int(device) if device.isdigit() else device)
    if not capture.isOpened():
        raise UserError(f"{device}: no camera there that OpenCV can open")

    def frames() -> Iterator[SourceFrame]:
        index = 0
        try:
            while True:
                ok, bgr = capture.read()
                if not ok:
                    return
                yield SourceFrame(f"{index:06d}", wall_ns(), jpeg(bgr[..., ::-1].copy()))
                index += 1
        finally:
            capture.release()

    return Source(frames(), live=True, description=f"camera {device}")


def recording(root: Path, format: str | None, options: ReadOptions, scratch: Path) -> Source:
    """Any recording ``fit`` reads: every colour frame with its recorded stamp and camera, depth beside it."""
    found = open_recording(root, format, options, scratch)
    if not found.pairs:
        raise UserError(f"{root}: no frames to stream")
    frames = (
        SourceFrame(
            p.name,
            p.stamp_ns if p.stamp_ns is not None else wall_ns(),
            p.rgb.read_bytes(),
            p.camera,
            p.depth,
            p.depth_scale,
        )
        for p in found.pairs
    )
    description = f"{found.format}, {len(found.pairs)} frames"
    return Source(frames, False, found.frame_id or DEFAULT_FRAME_ID, description, found.format in WRITTEN, True)


def is_depth_recording(path: Path) -> bool:
    """A Matroska file with a DEPTH track is an Azure Kinect (or Orbbec) recording; any other is a video."""
    if path.suffix.lower() != ".mkv":
        return False
    import av

    try:
        with av.open(str(path)) as container:
            return any((s.metadata.get("title") or "").upper() == "DEPTH" for s in container.streams)
    except av.error.FFmpegError:
        return True  # damaged: the Kinect reader says what is wrong with it, in words


def stream_source(source: str, format: str | None, options: ReadOptions, scratch: Path) -> Source:
    """A camera (``/dev/videoN``, an index), a video file, a folder of photos, or any recording."""
    if source.isdigit() or source.startswith("/dev/video"):
        return webcam(source)
    path = Path(source)
    if not path.exists():
        raise UserError(f"{source}: no such file or folder")
    if format is None and path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES and not is_depth_recording(path):
        return video(path)
    if format is None and path.is_dir() and not any(p.is_dir() for p in path.iterdir()):
        try:
            format = detect_format(path)
        except UserError:
            return photo_folder(path)
    return recording(path, format, options, scratch)
