"""Microsoft 7-Scenes sequences: frame-NNNNNN.color.jpg + frame-NNNNNN.depth.png (mm)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from contract.errors import UserError
from contract.geometry import Intrinsics
from trainer.data.frames import Frame, check_pair, parse_frame_ranges, read_depth_png, read_rgb

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


class SevenScenesReader:
    """One 7-Scenes sequence folder; ``frames`` selects frame numbers, e.g. '0-799'."""

    def __init__(self, root: Path, frames: str | None = None):
        self.root = Path(root)
        self.name = self.root.name
        self.licence = LICENCE
        available = {int(m.group(1)): p for p in self.root.iterdir() if (m := _FRAME.match(p.name))}
        if not available:
            raise FileNotFoundError(f"{self.root}: no frame-NNNNNN.color.jpg files")
        wanted = parse_frame_ranges(frames) if frames else sorted(available)
        missing = [n for n in wanted if n not in available]
        if missing:
            raise FileNotFoundError(f"{self.root}: frames {missing[:5]}{'...' if len(missing) > 5 else ''} are missing")
        self.colour_paths = [available[n] for n in wanted]
        self.frame_numbers = wanted
        k_path = self.root / "camera-intrinsics.txt"
        self.intrinsics = read_intrinsics_txt(k_path, 640, 480) if k_path.exists() else SEVEN_SCENES_DEFAULT

    def __len__(self) -> int:
        return len(self.colour_paths)

    def __getitem__(self, index: int) -> Frame:
        colour = self.colour_paths[index]
        depth_path = colour.with_name(f"frame-{self.frame_numbers[index]:06d}.depth.png")
        rgb = read_rgb(colour)
        depth = read_depth_png(depth_path, units_per_metre=1000.0)
        check_pair(rgb, depth, str(colour))
        intrinsics = self.intrinsics
        if (intrinsics.width, intrinsics.height) != (rgb.shape[1], rgb.shape[0]):
            intrinsics = intrinsics.resized(rgb.shape[1], rgb.shape[0])
        return Frame(rgb, depth, intrinsics, f"{self.name}/{self.frame_numbers[index]:06d}")
