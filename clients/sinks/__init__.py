"""Where a stream's answers go. Every sink takes the same ``DecodedFrame`` (one frame's depth, points and camera,
decoded once) and has ``write`` and ``close``; a new output is one small module beside these:

- ``folder``: NAME.depth.png (16-bit mm, byte for byte ``/depth``'s) and NAME.ply;
- ``bag``: a ROS 2 bag (MCAP) of the messages ``ros_messages`` makes;
- ``foxglove``: the same messages live, on a Foxglove WebSocket server.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Protocol

import numpy as np

from contract.geometry import Intrinsics


@dataclass
class DecodedFrame:
    """One frame's answer, decoded: depth in metres (0 where none), the points and their colours, and the
    camera the depth was inferred with; ``frame`` is the source's (``recordings.sources.SourceFrame``)."""

    frame: Any
    camera: Intrinsics
    metres: np.ndarray
    xyz: np.ndarray
    rgb: np.ndarray

    @property
    def name(self) -> str:
        return self.frame.name

    @property
    def stamp_ns(self) -> int:
        return self.frame.stamp_ns

    @property
    def photo(self) -> bytes:
        """The photo as it was sent (JPEG or PNG)."""
        return self.frame.data

    @cached_property
    def sensor_metres(self) -> np.ndarray | None:
        """A recording's own depth registered to colour, read only when a sink asks for it."""
        return self.frame.sensor_metres()


def decoded(frame: Any, header: dict[str, Any], payloads: dict[str, bytes]) -> DecodedFrame:
    """A stream answer (raw32 depth and raw points, as ``rgb2cloud stream`` asks for) as a ``DecodedFrame``."""
    from clients.stream import raw_depth, raw_points

    entries = {entry["kind"]: entry for entry in header["payloads"]}
    xyz, rgb = raw_points(entries["pointcloud"], payloads["pointcloud"])
    metres = raw_depth(entries["depth"], payloads["depth"])
    return DecodedFrame(frame, Intrinsics(**header["intrinsics"]), metres, xyz, rgb)


class Sink(Protocol):
    def write(self, answer: DecodedFrame) -> None: ...

    def close(self) -> None: ...
