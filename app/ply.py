"""Binary little-endian PLY: float x, y, z (metres) and uchar red, green, blue per vertex."""

from __future__ import annotations

import numpy as np

from contract.geometry import POINT


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
