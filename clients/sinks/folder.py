"""Answers as files: NAME.depth.png (16-bit millimetres) and, with ``pointcloud``, NAME.ply, written with the
service's own encoders so a PNG here is byte for byte what ``/depth`` returns."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clients.sinks import DecodedFrame


class FolderSink:
    def __init__(self, out: Path, pointcloud: bool):
        out.mkdir(parents=True, exist_ok=True)
        self.out, self.pointcloud = out, pointcloud

    def paths(self, name: str) -> list[Path]:
        """The files a frame called ``name`` is written to (all present: it was written)."""
        return [self.out / f"{name}.depth.png", *([self.out / f"{name}.ply"] if self.pointcloud else [])]

    def write(self, answer: DecodedFrame) -> None:
        from contract.encodings import encode_depth_png, encode_ply
        from contract.geometry import POINT

        depth_path, *ply_path = self.paths(answer.name)
        depth_path.write_bytes(encode_depth_png(answer.metres))
        if ply_path:
            points = np.empty(len(answer.xyz), dtype=POINT)
            for i, axis in enumerate("xyz"):
                points[axis] = answer.xyz[:, i]
            for i, channel in enumerate(("red", "green", "blue")):
                points[channel] = answer.rgb[:, i]
            ply_path[0].write_bytes(encode_ply(points))

    def close(self) -> None:
        """Each file is whole once written: nothing to finish."""
