"""The unit every reader yields, and the file decoding they share."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TypeVar

import numpy as np
from PIL import Image

from contract.errors import UserError
from contract.geometry import Intrinsics

T = TypeVar("T")

#: The first bytes of every PNG file.
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
#: Raw depth values that mean "no reading" in Kinect-style 16-bit PNGs.
MISSING_RAW = (0, 65535)
#: The pixels fit trains a recording at (the service's 640x480): larger recordings are scaled to it.
TRAINED_SIZE = (640, 480)
TRAINED_PIXELS = TRAINED_SIZE[0] * TRAINED_SIZE[1]
#: How many frames of a long recording fit keeps by default, evenly spread. A 30-minute fit on 2 CPU cores
#: trains about 1,650 steps of 4 views (docs/fit.md): about 6,600 views, so 600 frames are each seen about
#: 11 times, and a frame beyond them would be seen a handful of times while costing its decode and write.
DEFAULT_MAX_FRAMES = 600


@dataclass
class Frame:
    """One RGB-D pair: RGB uint8 HxWx3, depth float32 metres HxW (0 = missing)."""

    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: Intrinsics
    name: str


class FrameReader(Protocol):
    """A finite, indexable sequence of frames from one dataset."""

    name: str
    licence: str

    def __len__(self) -> int: ...

    def __getitem__(self, index: int) -> Frame: ...


@dataclass(frozen=True)
class RecordedPair:
    """One colour/depth pair on disk: the depth's raw units per metre and the colour camera.

    ``camera`` is for an image of its own size; a pair whose photo has another size gets
    the same camera resized (7-Scenes' calibration is for 640x480, whatever its files hold).
    """

    name: str
    rgb: Path
    depth: Path
    depth_scale: float
    camera: Intrinsics
    #: When the photo was taken, in nanoseconds, where the recording stamps its frames (a bag's header).
    stamp_ns: int | None = None


def read_pair(pair: RecordedPair, name: str | None = None) -> Frame:
    """The frame a pair holds, named ``name`` (default: the pair's)."""
    rgb = read_rgb(pair.rgb)
    depth = read_depth_png(pair.depth, pair.depth_scale)
    check_pair(rgb, depth, str(pair.rgb))
    camera = pair.camera
    if (camera.width, camera.height) != (rgb.shape[1], rgb.shape[0]):
        camera = camera.resized(rgb.shape[1], rgb.shape[0])
    return Frame(rgb, depth, camera, pair.name if name is None else name)


class PairsReader:
    """A ``FrameReader`` over colour/depth files: every format but NYU's arrays is this once listed.

    ``skipped`` says which frames a reader left out and why, and ``notes`` what it found (a bag's
    topics, a phone's confidence), for ``fit`` to print.
    """

    def __init__(
        self,
        name: str,
        licence: str,
        pairs: list[RecordedPair],
        skipped: list[tuple[str, str]] | None = None,
        notes: list[str] | None = None,
        frame_id: str | None = None,
    ):
        self.name, self.licence, self.pairs = name, licence, pairs
        self.skipped = skipped or []
        self.notes = notes or []
        #: The colour camera's frame, where the recording names one (a bag's CameraInfo header).
        self.frame_id = frame_id

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, index: int) -> Frame:
        pair = self.pairs[index]
        return read_pair(pair, f"{self.name}/{pair.name}")

    def selected(self, indices: list[int]) -> PairsReader:
        """The same reader holding only the pairs at ``indices``."""
        pairs = [self.pairs[i] for i in indices]
        return PairsReader(self.name, self.licence, pairs, self.skipped, self.notes, self.frame_id)


#: Raw units per metre of the depth PNGs readers write out (a bag's messages, a phone's maps).
WRITTEN_DEPTH_SCALE = 1000.0


def nearest_stamp(ordered: np.ndarray, t: float) -> tuple[int, float] | None:
    """The index in ``ordered`` (sorted times) of the time nearest ``t``, and how far it is; None when empty.

    How a reader pairs a colour frame with the depth frame taken closest to it."""
    j = int(np.searchsorted(ordered, t))
    near = [k for k in (j - 1, j) if 0 <= k < len(ordered)]
    if not near:
        return None
    best = min(near, key=lambda k: abs(ordered[k] - t))
    return best, float(abs(ordered[best] - t))


def spread(items: Sequence[T], count: int | None) -> list[T]:
    """At most ``count`` of ``items`` (all when ``count`` is None or 0), evenly spread from the first to the last."""
    if not count or len(items) <= count:
        return list(items)
    return [items[i] for i in np.linspace(0, len(items) - 1, count).round().astype(int)]


def kept_note(total: int, kept: int, every: int, max_frames: int | None, unit: str = "frames") -> str:
    """What ``spread(items[::every], max_frames)`` kept of ``total``, and why: the line fit prints."""
    how = f"every {every}th {unit[:-1]}" if every > 1 else f"every {unit[:-1]}"
    if kept < len(range(0, total, max(1, every))):
        how += f", capped at {kept} evenly spread (--max-frames {max_frames}; 0 keeps all)"
    return f"kept {kept} of {total} {unit}: {how}"


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) from an image file's header, without decoding it."""
    with Image.open(path) as im:
        return im.size


def read_rgb(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), dtype=np.uint8)


def read_depth_png(path: Path, units_per_metre: float) -> np.ndarray:
    """A 16-bit depth PNG -> float32 metres, with 0 and 65535 mapped to 0 (missing)."""
    with Image.open(path) as im:
        raw = np.asarray(im)
    if raw.ndim != 2 or raw.dtype not in (np.uint16, np.int32, np.uint8):
        raise UserError(f"{path}: expected a single-channel 16-bit depth PNG, got {raw.dtype} {raw.shape}")
    raw = raw.astype(np.int64)
    depth = (raw / units_per_metre).astype(np.float32)
    depth[np.isin(raw, MISSING_RAW)] = 0.0
    return depth


def check_pair(rgb: np.ndarray, depth: np.ndarray, where: str) -> None:
    if rgb.shape[:2] != depth.shape:
        raise UserError(f"{where}: RGB is {rgb.shape[1]}x{rgb.shape[0]} but depth is {depth.shape[1]}x{depth.shape[0]}")


def parse_frame_ranges(text: str) -> list[int]:
    """'0-799' or '0-9,20,30-39' -> sorted unique frame numbers (inclusive ranges)."""
    numbers: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            start, end = int(lo), int(hi) if sep else int(lo)
        except ValueError as e:
            raise UserError(f"bad frame range {part!r} in {text!r}") from e
        if end < start:
            raise UserError(f"frame range {part!r} runs backwards")
        numbers.update(range(start, end + 1))
    if not numbers:
        raise UserError(f"no frames in {text!r}")
    return sorted(numbers)
