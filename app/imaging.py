"""Uploads to RGB arrays, and depth to a colour preview: the service's image edges.

Decoding is defensive: the pixel count is checked from the header before any
pixel is decoded, truncated files are errors (never silently grey), EXIF
orientation is applied, and every Pillow mode becomes RGB uint8.
"""

from __future__ import annotations

import io
import warnings

import numpy as np
from PIL import ExifTags, Image, ImageOps, UnidentifiedImageError

from app.camera import QUARTER_TURNS, exif_focal
from contract.colormap import colorize
from contract.encodings import PNG_COMPRESS_LEVEL

READABLE = "JPEG, PNG, WebP, TIFF, BMP, GIF"


class BadImage(Exception):
    """An upload we refuse, with the HTTP status and a message for the client."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


def _to_rgb(im: Image.Image) -> np.ndarray:
    """Any Pillow mode -> HxWx3 uint8 (16-bit and float greys are scaled, alpha dropped)."""
    if im.mode in ("I;16", "I;16L", "I;16B", "I;16N", "I"):
        grey = np.asarray(im, dtype=np.float64)
        top = 65535.0 if grey.max(initial=0) > 255 or im.mode.startswith("I;16") else 255.0
        grey = np.clip(grey / top * 255.0 + 0.5, 0, 255).astype(np.uint8)
        return np.repeat(grey[..., None], 3, axis=2)
    if im.mode == "F":
        grey = np.nan_to_num(np.asarray(im, dtype=np.float64))
        lo, hi = grey.min(initial=0), grey.max(initial=0)
        grey = ((grey - lo) / (hi - lo if hi > lo else 1.0) * 255.0 + 0.5).astype(np.uint8)
        return np.repeat(grey[..., None], 3, axis=2)
    if im.mode == "P" and "transparency" in im.info:
        im = im.convert("RGBA")
    return np.asarray(im.convert("RGB"), dtype=np.uint8)


#: Pillow's names for JPEG files: plain, and the multi-picture JPEG some cameras and phones write.
JPEG_FORMATS = ("JPEG", "MPO")


class Upload:
    """An upload whose header was read and checked; its pixels are decoded by ``rgb``, at full or half size.

    Split so that the camera, which the upright size and EXIF give, is known before any pixel is decoded: a
    photo the generator sees at exactly half its size can then be decoded at half (``rgb``'s ``at``).
    """

    def __init__(self, data: bytes, image: Image.Image):
        self.data = data
        #: The image whose header was read, decoded by the first ``rgb``; later calls open the data again.
        self._unread: Image.Image | None = image
        try:
            image.seek(0)  # animated formats: the first frame
            #: The focal length (fx, fy) in the upright photo's pixels that its EXIF gives, or None.
            self.exif_focal = exif_focal(image)
            self.turned = image.getexif().get(ExifTags.Base.Orientation) in QUARTER_TURNS
        except Exception as e:  # a header whose EXIF or frames cannot be read
            raise BadImage(400, f"the image data is truncated or corrupt: {e}") from None
        width, height = image.size
        #: The upright photo's (width, height), its EXIF orientation applied.
        self.size = (height, width) if self.turned else (width, height)

    def rgb(self, at: tuple[int, int] | None = None) -> np.ndarray:
        """The upright photo, HxWx3 uint8; at ``at`` (width, height) where that is exactly half its size and it
        is a JPEG, otherwise at its own size, so callers check the size they get. Each call decodes afresh.

        A JPEG is decoded at half by libjpeg's DCT scaling: a quarter of the pixels are computed and none is
        resampled afterwards, in about half the time of a full decode and its 2x2 mean, for depth whose
        held-out δ1 moved by 0.0001 at most (``bench/jpeg_half.py``, docs/benchmarks.md).
        """
        im, self._unread = self._unread, None
        try:
            if im is None:
                im = Image.open(io.BytesIO(self.data))
                im.seek(0)
            if at is not None and (2 * at[0], 2 * at[1]) == self.size and im.format in JPEG_FORMATS:
                im.draft("RGB", (at[1], at[0]) if self.turned else at)
            im.load()
            return _to_rgb(ImageOps.exif_transpose(im))
        except Exception as e:  # truncated or corrupt pixel data
            raise BadImage(400, f"the image data is truncated or corrupt: {e}") from None


def open_upload(data: bytes, max_pixels: int, subject: str = "the 'image' field") -> Upload:
    """Upload bytes -> its checked header (``Upload``), or ``BadImage`` that names ``subject``: no pixel is
    decoded before the pixel count is within ``max_pixels``."""
    if not data:
        raise BadImage(400, f"{subject} is empty")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            im = Image.open(io.BytesIO(data))
    except UnidentifiedImageError:
        raise BadImage(415, f"{subject} is not an image we can read ({READABLE})") from None
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as e:
        raise BadImage(413, f"image has too many pixels: {e}") from None
    except Exception as e:  # Pillow raises many types on malformed headers
        raise BadImage(400, f"the image header is corrupt: {e}") from None
    width, height = im.size
    if width < 1 or height < 1:
        raise BadImage(400, f"image is {width}x{height}")
    if width * height > max_pixels:
        raise BadImage(413, f"image is {width}x{height} = {width * height} pixels; the limit is {max_pixels}")
    return Upload(data, im)


def encode_colormap_png(metres: np.ndarray, vmin: float, vmax: float) -> bytes:
    """An 8-bit RGB preview for people (near blue, far red)."""
    buffer = io.BytesIO()
    Image.fromarray(colorize(metres, vmin, vmax)).save(buffer, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
    return buffer.getvalue()
