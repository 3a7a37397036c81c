"""The one writer of frames that readers must write out: a photo and a 16-bit millimetre depth PNG per pair.

Bags, Azure Kinect recordings and phone exports hold their frames in containers, so their readers
write each kept pair out as files once, and the rest of ``fit`` reads them like any other
recording. Each is written at the size fit trains at (``TRAINED_PIXELS``, the service's 640x480
pixel count): writing larger costs decode, resize and disk time for pixels training never sees.
A photo recorded as a JPEG or PNG at that size already is kept byte for byte; every other photo
is written as a JPEG of quality 95. Depth arrives registered to the written photo (a bag's, a
Kinect's), or on a coarser grid over the same view (a phone's LiDAR), which
``recordings.registration.upsample_depth`` brings to the photo without inventing depth across a step.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from contract.geometry import Intrinsics
from recordings.frames import PNG_MAGIC, TRAINED_PIXELS, WRITTEN_DEPTH_SCALE, PairsReader, RecordedPair
from recordings.registration import upsample_depth

#: A photo's pixels: HxWx3 uint8 RGB, or a PIL image.
Photo = np.ndarray | Image.Image


class PairWriter:
    """Writes pairs under ``out`` as ``color/NAME.jpg`` (or ``.png``, as recorded) and ``depth/NAME.png``."""

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

    def photo(self, name: str, photo: Photo, encoded: bytes | None = None) -> tuple[Path, np.ndarray]:
        """Write one photo at the written size; the file and its pixels as written.

        ``encoded``: the JPEG or PNG the pixels were decoded from, as recorded, kept byte for byte when
        the photo is already at the written size. Decoding is the reader's, so that a damaged photo is
        skipped there, while a failed write (a full disk) is never taken for damage.
        """
        image = photo if isinstance(photo, Image.Image) else Image.fromarray(photo)
        if encoded is not None and image.size == self.size:
            path = self.out / "color" / f"{name}{'.png' if encoded[:8] == PNG_MAGIC else '.jpg'}"
            path.write_bytes(encoded)
            return path, np.asarray(image)
        if image.size != self.size:
            image = image.resize(self.size, Image.Resampling.BILINEAR)
        pixels = np.asarray(image.convert("RGB"))
        path = self.out / "color" / f"{name}.jpg"
        Image.fromarray(pixels).save(path, quality=95)
        return path, pixels

    def depth(self, name: str, metres: np.ndarray, photo: np.ndarray | None = None) -> Path:
        """Write one depth map in millimetres: at the written size already, or upsampled to ``photo``'s pixels."""
        if metres.shape != (self.size[1], self.size[0]):
            if photo is None:
                raise ValueError(f"depth of {metres.shape} for a {self.size} photo, and no photo to upsample it to")
            metres = upsample_depth(metres, photo)
        millimetres = np.clip(np.rint(metres * WRITTEN_DEPTH_SCALE), 0, 65535).astype(np.uint16)
        path = self.out / "depth" / f"{name}.png"
        Image.fromarray(millimetres).save(path)
        return path

    def write(self, name: str, photo: Photo, metres: np.ndarray) -> tuple[str, Path, Path]:
        """One pair: the photo at the written size, and its depth (registered to it, or coarser and upsampled)."""
        colour, pixels = self.photo(name, photo)
        return name, colour, self.depth(name, metres, pixels)


def damaged_note(damaged: list[tuple[str, str]]) -> str:
    """The line fit prints for frames skipped as damaged: how many, and the first few with why."""
    shown = ", ".join(f"{name} ({why})" for name, why in damaged[:3])
    return f"damaged frames skipped: {len(damaged)} ({shown}{', ...' if len(damaged) > 3 else ''})"


def written_pairs(
    name: str,
    files: list[tuple[str, Path, Path]],
    camera: Intrinsics,
    skipped: list[tuple[str, str]],
    notes: list[str],
    stamps: dict[str, int] | None = None,
    frame_id: str | None = None,
) -> PairsReader:
    """The frames a reader wrote out: (name, colour file, millimetre depth file) in time order, in ``camera``,
    with each photo's stamp in nanoseconds and the colour camera's frame where the recording has them."""
    stamps = stamps or {}
    pairs = [RecordedPair(n, rgb, depth, WRITTEN_DEPTH_SCALE, camera, stamps.get(n)) for n, rgb, depth in files]
    return PairsReader(name, "", pairs, skipped, notes, frame_id)
