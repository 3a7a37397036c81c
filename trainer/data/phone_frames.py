"""Phone LiDAR and Azure Kinect frames written out for fit, by the one writer their readers use.

Phone exports hold photos far larger than fit trains at (1920x1440 from current iPhones) and
depth far smaller (256x192). Each kept frame is written once, at the size fit trains at
(``TRAINED_PIXELS``, the service's 640x480 pixel count): writing larger costs decode, resize
and disk time for pixels training never sees. Depth is upsampled to the written photo by
``trainer.registration.upsample_depth``: smooth within a surface, none invented across a step.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from contract.geometry import Intrinsics
from trainer.data.folders import CameraFile
from trainer.data.frames import DEFAULT_MAX_FRAMES, TRAINED_PIXELS, kept_note, spread
from trainer.registration import upsample_depth

#: Depth pixels of lower confidence are dropped by default: ARKit's 2 is "high".
DEFAULT_MIN_CONFIDENCE = 2


@dataclass(frozen=True)
class PhoneOptions:
    """Which frames of a phone export to write, which depth to trust, and camera overrides.

    ``camera`` (``--fx`` ...) is in the pixels of the photos as recorded, applied before any frame is
    resized or written.
    """

    every: int = 1
    max_frames: int | None = DEFAULT_MAX_FRAMES
    min_confidence: int = DEFAULT_MIN_CONFIDENCE
    camera: CameraFile = field(default_factory=CameraFile)

    def kept(self, numbers: Sequence[int]) -> list[int]:
        """Every ``every``-th frame number, at most ``max_frames`` of them evenly spread."""
        return spread(list(numbers)[:: max(1, self.every)], self.max_frames)

    def note(self, total: int, kept: int) -> str:
        """What was kept of a recording of ``total`` frames, and why."""
        return kept_note(total, kept, self.every, self.max_frames)


class FrameWriter:
    """Writes (photo, depth in metres) pairs under ``out`` as colour JPEG and 16-bit millimetre PNG."""

    def __init__(self, out: Path, width: int, height: int):
        self.size = self.written_size(width, height)
        self.out = Path(out)
        (self.out / "color").mkdir(parents=True, exist_ok=True)
        (self.out / "depth").mkdir(parents=True, exist_ok=True)

    @staticmethod
    def written_size(width: int, height: int) -> tuple[int, int]:
        """The size a ``width`` x ``height`` photo is written at: at most ``TRAINED_PIXELS``, the same shape."""
        scale = min(1.0, float(np.sqrt(TRAINED_PIXELS / (width * height))))
        return round(width * scale), round(height * scale)

    def camera(self, native: Intrinsics) -> Intrinsics:
        """The photos' camera, ``native`` for the size they were recorded at, as written."""
        return native.resized(*self.size)

    def write(self, name: str, rgb: np.ndarray | Image.Image, metres: np.ndarray) -> tuple[str, Path, Path]:
        """One pair, the photo resized to the written size and the depth upsampled to it (depth already registered
        at the written size, as a Kinect reader's, is written as it is)."""
        image = rgb if isinstance(rgb, Image.Image) else Image.fromarray(rgb)
        if image.size != self.size:
            image = image.resize(self.size, Image.Resampling.BILINEAR)
        photo = np.asarray(image.convert("RGB"))
        if metres.shape != photo.shape[:2]:
            metres = upsample_depth(metres, photo)
        millimetres = np.clip(np.rint(metres * 1000.0), 0, 65535).astype(np.uint16)
        colour, depth = self.out / "color" / f"{name}.jpg", self.out / "depth" / f"{name}.png"
        Image.fromarray(photo).save(colour, quality=95)
        Image.fromarray(millimetres).save(depth)
        return name, colour, depth
