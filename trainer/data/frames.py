"""The unit every reader yields, and the file decoding they share."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from PIL import Image

from contract.errors import UserError
from contract.geometry import Intrinsics

#: Raw depth values that mean "no reading" in Kinect-style 16-bit PNGs.
MISSING_RAW = (0, 65535)


@dataclass
class Frame:
    """One RGB-D pair: RGB uint8 HxWx3, depth float32 metres HxW (0 = missing)."""

    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: Intrinsics
    name: str


@dataclass
class WrittenPairs:
    """A recording whose frames a reader wrote out as files (a bag's messages, a phone's video and depth maps).

    ``pairs`` are (name, colour file, depth file in 16-bit millimetres) in time order, the depth
    already in ``camera``, the colour camera; ``skipped`` says which frames were left out and why,
    and ``notes`` what the reader found, for a user to see.
    """

    pairs: list[tuple[str, Path, Path]]
    camera: Intrinsics
    skipped: list[tuple[str, str]]
    notes: list[str] = field(default_factory=list)


class FrameReader(Protocol):
    """A finite, indexable sequence of frames from one dataset."""

    name: str
    licence: str

    def __len__(self) -> int: ...

    def __getitem__(self, index: int) -> Frame: ...


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
