"""Binary little-endian PLY: float x, y, z (metres) and uchar red, green, blue per vertex."""

from __future__ import annotations

import numpy as np

VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])


def encode_ply(points: np.ndarray, colours: np.ndarray) -> bytes:
    """(N, 3) float points and (N, 3) uint8 colours -> PLY bytes, in one pass over memory."""
    vertices = np.empty(len(points), dtype=VERTEX)
    for i, axis in enumerate("xyz"):
        vertices[axis] = points[:, i]
    for i, channel in enumerate(("red", "green", "blue")):
        vertices[channel] = colours[:, i]
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment rgb2cloud: camera frame, x right, y down, z forward, metres\n"
        f"element vertex {len(points)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    return header.encode("ascii") + vertices.tobytes()
