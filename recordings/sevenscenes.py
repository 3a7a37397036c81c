"""Microsoft 7-Scenes sequences: frame-NNNNNN.color.jpg + frame-NNNNNN.depth.png (mm)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from contract.errors import UserError
from contract.geometry import Intrinsics
from recordings.frames import PairsReader, RecordedPair, parse_frame_ranges

#: 7-Scenes' published depth-camera calibration, used when camera-intrinsics.txt is absent.
SEVEN_SCENES_DEFAULT = Intrinsics(fx=585.0, fy=585.0, cx=320.0, cy=240.0, width=640, height=480)
LICENCE = "Microsoft 7-Scenes: Microsoft Research licence, non-commercial use only"
_FRAME = re.compile(r"^frame-(\d{6})\.color\.(jpg|png)$")


def read_intrinsics_txt(path: Path, width: int, height: int) -> Intrinsics:
    """A 3x3 camera matrix in plain text (7-Scenes' camera-intrinsics.txt)."""
    k = np.loadtxt(path, dtype=np.float64)
    if k.shape != (3, 3):
        raise UserError(f"{path}: expected a 3x3 camera matrix, got shape {k.shape}")
    return Intrinsics(fx=k[0, 0], fy=k[1, 1], cx=k[0, 2], cy=k[1, 2], width=width, height=height)


class SevenScenesReader(PairsReader):
    """One 7-Scenes sequence folder; ``frames`` selects frame numbers, e.g. '0-799'."""

    def __init__(self, root: Path, frames: str | None = None):
        self.root = Path(root)
        available = {int(m.group(1)): p for p in self.root.iterdir() if (m := _FRAME.match(p.name))}
        if not available:
            raise UserError(f"{self.root}: no frame-NNNNNN.color.jpg files")
        wanted = parse_frame_ranges(frames) if frames else sorted(available)
        missing = [n for n in wanted if n not in available]
        if missing:
            raise UserError(f"{self.root}: frames {missing[:5]}{'...' if len(missing) > 5 else ''} are missing")
        k_path = self.root / "camera-intrinsics.txt"
        self.intrinsics = read_intrinsics_txt(k_path, 640, 480) if k_path.exists() else SEVEN_SCENES_DEFAULT
        pairs = [
            RecordedPair(
                f"{n:06d}", available[n], available[n].with_name(f"frame-{n:06d}.depth.png"), 1000.0, self.intrinsics
            )
            for n in wanted
        ]
        super().__init__(self.root.name, LICENCE, pairs)
