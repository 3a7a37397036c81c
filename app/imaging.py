"""Uploads to RGB arrays, and depth to a colour preview: the service's image edges.

Decoding is defensive: the pixel count is checked from the header before any
pixel is decoded, truncated files are errors (never silently grey), EXIF
orientation is applied, and every Pillow mode becomes RGB uint8.
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from app.camera import exif_focal
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


@dataclass(frozen=True)
class Photo:
    """The upright photo as HxWx3 uint8 RGB, and the focal length (fx, fy) in its pixels that its EXIF gives."""

    rgb: np.ndarray
    exif_focal: tuple[float, float] | None


def decode_image(data: bytes, max_pixels: int, subject: str = "the 'image' field") -> Photo:
    """Upload bytes -> the upright RGB photo and its EXIF focal length, or ``BadImage`` that names ``subject``."""
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
    try:
        im.seek(0)  # animated formats: the first frame
        im.load()
        focal = exif_focal(im)
        return Photo(_to_rgb(ImageOps.exif_transpose(im)), focal)
    except Exception as e:  # truncated or corrupt pixel data
        raise BadImage(400, f"the image data is truncated or corrupt: {e}") from None


def encode_colormap_png(metres: np.ndarray, vmin: float, vmax: float) -> bytes:
    """An 8-bit RGB preview for people (near blue, far red)."""
    buffer = io.BytesIO()
    Image.fromarray(colorize(metres, vmin, vmax)).save(buffer, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
    return buffer.getvalue()
