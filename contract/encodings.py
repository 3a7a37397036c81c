"""The depth and point-cloud encodings the service sends and a client writes to files.

One module for both sides, so a depth PNG or PLY that ``rgb2cloud stream`` writes from a stream's raw
answer is byte for byte what ``POST /depth`` and ``/pointcloud`` send: 16-bit PNG in millimetres,
the stream's raw16 and raw32 depth, and binary little-endian PLY (float x, y, z in metres, uchar
red, green, blue per vertex).
"""

from __future__ import annotations

import struct

import numpy as np
from isal import isal_zlib

from contract.geometry import POINT

#: Light compression: deflate is most of a PNG's encode time.
PNG_COMPRESS_LEVEL = 1
#: The service's default limit on a stream frame's pixels (RGB2CLOUD_STREAM_MAX_PIXELS): 4K UHD.
STREAM_MAX_PIXELS = 3840 * 2160
#: The most bytes one message of a stream answer takes per pixel of the photo: a raw or PLY cloud with a point
#: for every pixel (a ``POINT`` each; raw32 depth is 4 bytes a pixel, the JSON header far less), rounded up.
MESSAGE_BYTES_PER_PIXEL = POINT.itemsize + 1


def png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", isal_zlib.crc32(data, isal_zlib.crc32(kind)))


def depth_millimetres(metres: np.ndarray, dtype: str = "<u2") -> np.ndarray:
    """Metres -> whole millimetres as 16-bit integers (0 = no depth; beyond 65.535 m clipped), in ``dtype``'s
    byte order: big-endian for PNG, little-endian for the stream's raw depth.

    In place on one copy (float32, or float64 for float64 depth), as every frame's depth passes here: about
    two thirds of the time of masking, rounding and clipping into fresh arrays at 640x480 (the stream's
    ``encode`` stage, docs/benchmarks.md).
    """
    with np.errstate(over="ignore"):  # a finite depth too far for its type: infinite millimetres, clipped below
        mm = np.multiply(metres, 1000.0, dtype=np.result_type(metres, np.float32))
    mm[~(np.isfinite(metres) & (metres > 0))] = 0
    np.rint(mm, out=mm)
    np.minimum(mm, 65535, out=mm)
    return mm.astype(dtype)


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
        + png_chunk(b"IHDR", header)
        + png_chunk(b"IDAT", isal_zlib.compress(rows, PNG_COMPRESS_LEVEL))
        + png_chunk(b"IEND", b"")
    )


def encode_ply(points: np.ndarray) -> bytes:
    """``POINT`` records -> PLY bytes. The records already are the vertex layout: one copy."""
    if points.dtype != POINT:
        raise TypeError(f"expected contract.geometry.POINT records, got {points.dtype}")
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment rgb2cloud: camera frame, x right, y down, z forward, metres\n"
        f"element vertex {len(points)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    return b"".join((header.encode("ascii"), np.ascontiguousarray(points).view(np.uint8)))
