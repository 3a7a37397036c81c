"""A CSV manifest of RGB-D pairs, for any dataset without a dedicated reader.

Header (one row per pair; paths relative to the CSV's folder)::

    rgb,depth,depth_scale,fx,fy,cx,cy

``depth_scale`` is Open3D's: raw depth units per metre (1000 for millimetres,
5000 for TUM). Intrinsics are in pixels of that row's image. Raw 0 and 65535
are missing depth.
"""

from __future__ import annotations

import csv
from pathlib import Path

from contract.errors import UserError
from contract.geometry import Intrinsics
from trainer.data.frames import Frame, check_pair, read_depth_png, read_rgb

COLUMNS = ("rgb", "depth", "depth_scale", "fx", "fy", "cx", "cy")


class ManifestReader:
    def __init__(self, csv_path: Path, licence: str | None = None):
        self.path = Path(csv_path)
        self.name = self.path.stem
        self.licence = licence or ""
        with open(self.path, newline="") as f:
            reader = csv.DictReader(f)
            missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise UserError(f"{self.path}: missing columns {missing}; expected {','.join(COLUMNS)}")
            self.rows = []
            for line, row in enumerate(reader, 2):
                try:
                    numbers = {k: float(row[k]) for k in COLUMNS[2:]}
                except (TypeError, ValueError) as e:
                    raise UserError(f"{self.path}:{line}: {e}") from e
                if numbers["depth_scale"] <= 0 or numbers["fx"] <= 0 or numbers["fy"] <= 0:
                    raise UserError(f"{self.path}:{line}: depth_scale, fx and fy must be positive")
                self.rows.append((row["rgb"], row["depth"], numbers))
        if not self.rows:
            raise UserError(f"{self.path}: no rows")

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, index: int) -> Frame:
        rgb_file, depth_file, n = self.rows[index]
        base = self.path.parent
        rgb = read_rgb(base / rgb_file)
        depth = read_depth_png(base / depth_file, n["depth_scale"])
        check_pair(rgb, depth, str(base / rgb_file))
        intrinsics = Intrinsics(n["fx"], n["fy"], n["cx"], n["cy"], rgb.shape[1], rgb.shape[0])
        return Frame(rgb, depth, intrinsics, f"{self.name}/{Path(rgb_file).stem}")
