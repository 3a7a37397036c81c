"""The client side of ``/v1/stream`` for tests and benchmarks: open a stream, read an answer, unpack payloads.

Written against the protocol as docs/api.md states it, with the ``websockets`` library, not the
service's code: what the tests check is what any client would receive.
"""

from __future__ import annotations

import json
from typing import Any
from urllib.parse import urlencode

import numpy as np
from websockets.sync.client import ClientConnection, connect


def stream_url(service_url: str, **options: Any) -> str:
    """``ws://host:port/v1/stream?...`` for a service's ``http://`` URL and the stream's options."""
    query = urlencode({k: v for k, v in options.items() if v is not None})
    return service_url.replace("http://", "ws://", 1) + "/v1/stream" + (f"?{query}" if query else "")


def open_stream(service_url: str, origin: str | None = None, **options: Any) -> ClientConnection:
    """A stream, with no compression (as browsers' frames are JPEG anyway) and no message size limit."""
    headers = {"Origin": origin} if origin else None
    return connect(
        stream_url(service_url, **options), max_size=None, compression=None, additional_headers=headers, open_timeout=30
    )


def receive(socket: ClientConnection, timeout: float | None = 120) -> tuple[dict[str, Any], list[bytes]]:
    """One answer: the JSON header, and the binary payloads it announces (none for an error or options)."""
    header = json.loads(socket.recv(timeout=timeout))
    payloads = [socket.recv(timeout=timeout) for _ in header.get("payloads", [])]
    assert all(isinstance(p, bytes) for p in payloads), "a payload arrived as text"
    return header, payloads


def raw_depth(entry: dict[str, Any], body: bytes) -> np.ndarray:
    """A ``raw16`` depth payload as metres, height x width (0 where there is no depth)."""
    mm = np.frombuffer(body, dtype="<u2").reshape(entry["height"], entry["width"])
    return mm.astype(np.float64) / 1000.0


def raw_points(entry: dict[str, Any], body: bytes) -> tuple[np.ndarray, np.ndarray]:
    """A ``raw`` point cloud payload as (N x 3 float32 x, y, z; N x 3 uint8 r, g, b)."""
    count = entry["points"]
    xyz = np.frombuffer(body, dtype="<f4", count=3 * count).reshape(count, 3)
    rgb = np.frombuffer(body, dtype=np.uint8, offset=12 * count).reshape(count, 3)
    return xyz, rgb
