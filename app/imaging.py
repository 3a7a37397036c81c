"""Uploads to RGB arrays, and depth to PNG: the service's image edges.

Decoding is defensive: the pixel count is checked from the header before any
pixel is decoded, truncated files are errors (never silently grey), EXIF
orientation is applied, and every Pillow mode becomes RGB uint8.
"""

from __future__ import annotations

import io
import struct
import warnings
from dataclasses import dataclass

import numpy as np
from isal import isal_zlib
from PIL import Image, ImageOps, UnidentifiedImageError

from app.camera import exif_focal
from contract.colormap import colorize

READABLE = "JPEG, PNG, WebP, TIFF, BMP, GIF"
#: Light compression: deflate is most of a PNG's encode time.
PNG_COMPRESS_LEVEL = 1


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


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", isal_zlib.crc32(data, isal_zlib.crc32(kind)))


def depth_millimetres(metres: np.ndarray, dtype: str = "<u2") -> np.ndarray:
    """Metres -> whole millimetres as 16-bit integers (0 = no depth; beyond 65.535 m clipped), in ``dtype``'s
    byte order: big-endian for PNG, little-endian for the stream's raw depth."""
    mm = np.where(np.isfinite(metres) & (metres > 0), np.rint(metres * 1000.0), 0)
    return np.clip(mm, 0, 65535).astype(dtype)


def depth_metres(metres: np.ndarray) -> np.ndarray:
    """Metres as little-endian float32, row-major, 0 where there is no depth: the stream's ``raw32``."""
    values = np.where(np.isfinite(metres) & (metres > 0), metres, 0)
    return np.ascontiguousarray(values, dtype="<f4")


def depth_png_rows(metres: np.ndarray) -> np.ndarray:
    """Millimetres as 16-bit big-endian PNG scanlines, each prefixed by the "Up" filter.

    "Up" stores each byte minus the byte above: the depth is smooth, so most of
    these are near zero and deflate well, without the per-row filter search that
    made Pillow's encoder 1.8x slower for the same size.
    """
    height, width = metres.shape
    big_endian = depth_millimetres(metres, ">u2").view(np.uint8).reshape(height, 2 * width)
    rows = np.empty((height, 2 * width + 1), dtype=np.uint8)
    rows[:, 0] = 2  # filter type "Up" (the first row sees zeros above it)
    rows[0, 1:] = big_endian[0]
    np.subtract(big_endian[1:], big_endian[:-1], out=rows[1:, 1:])
    return rows


def encode_depth_png(metres: np.ndarray) -> bytes:
    """16-bit single-channel PNG in millimetres; 0 = no depth.

    The scanlines are deflated by ISA-L at level 1: a standard zlib stream, made
    several times faster than zlib's own level 1 at about the same size
    (bench/serving.py compares the two). Tests decode the result with Pillow.
    """
    rows = depth_png_rows(metres)
    height, width = rows.shape[0], (rows.shape[1] - 1) // 2
    header = struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)  # 16-bit greyscale
    return (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", header)
        + _png_chunk(b"IDAT", isal_zlib.compress(rows, PNG_COMPRESS_LEVEL))
        + _png_chunk(b"IEND", b"")
    )


def encode_colormap_png(metres: np.ndarray, vmin: float, vmax: float) -> bytes:
    """An 8-bit RGB preview for people (near blue, far red)."""
    buffer = io.BytesIO()
    Image.fromarray(colorize(metres, vmin, vmax)).save(buffer, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
    return buffer.getvalue()
