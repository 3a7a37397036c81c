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
from recordings.frames import PairsReader, RecordedPair, image_size

COLUMNS = ("rgb", "depth", "depth_scale", "fx", "fy", "cx", "cy")


class ManifestReader(PairsReader):
    """The pairs a manifest lists; each row's intrinsics are for its own photo's size."""

    def __init__(self, csv_path: Path, licence: str | None = None):
        self.path = Path(csv_path)
        with open(self.path, newline="") as f:
            reader = csv.DictReader(f)
            missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise UserError(f"{self.path}: missing columns {missing}; expected {','.join(COLUMNS)}")
            pairs = [self._pair(row, line) for line, row in enumerate(reader, 2)]
        if not pairs:
            raise UserError(f"{self.path}: no rows")
        super().__init__(self.path.stem, licence or "", pairs)

    def _pair(self, row: dict[str, str], line: int) -> RecordedPair:
        try:
            numbers = {k: float(row[k]) for k in COLUMNS[2:]}
        except (TypeError, ValueError) as e:
            raise UserError(f"{self.path}:{line}: {e}") from e
        if numbers["depth_scale"] <= 0 or numbers["fx"] <= 0 or numbers["fy"] <= 0:
            raise UserError(f"{self.path}:{line}: depth_scale, fx and fy must be positive")
        rgb = self.path.parent / row["rgb"]
        try:
            width, height = image_size(rgb)
        except OSError as e:
            raise UserError(f"{self.path}:{line}: cannot read {rgb}: {e}") from None
        k = Intrinsics(numbers["fx"], numbers["fy"], numbers["cx"], numbers["cy"], width, height)
        return RecordedPair(Path(row["rgb"]).stem, rgb, self.path.parent / row["depth"], numbers["depth_scale"], k)


def write_manifest(path: Path, pairs: list[RecordedPair]) -> Path:
    """A CSV manifest of ``pairs`` with absolute paths, which ``ManifestReader`` reads back."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        for p in pairs:
            k, size = p.camera, image_size(p.rgb)
            if size != (k.width, k.height):
                k = k.resized(*size)
            writer.writerow([p.rgb.resolve(), p.depth.resolve(), p.depth_scale, k.fx, k.fy, k.cx, k.cy])
    return path
