"""TUM RGB-D sequences: rgb.txt and depth.txt associated by timestamp; depth / 5000."""

from __future__ import annotations

import bisect
from pathlib import Path

from contract.errors import UserError
from contract.geometry import Intrinsics
from recordings.frames import PairsReader, RecordedPair

LICENCE = "TUM RGB-D benchmark: CC BY 4.0"
DEPTH_UNITS_PER_METRE = 5000.0
MAX_DIFFERENCE_S = 0.02

#: TUM's published calibrations per sensor; fr3 is also the paper's Kinect default.
TUM_CAMERAS = {
    "freiburg1": Intrinsics(517.3, 516.5, 318.6, 255.3, 640, 480),
    "freiburg2": Intrinsics(520.9, 521.0, 325.1, 249.7, 640, 480),
    "freiburg3": Intrinsics(535.4, 539.2, 320.1, 247.6, 640, 480),
}


def read_file_list(path: Path) -> list[tuple[float, str]]:
    """TUM's 'timestamp filename' lists; '#' starts a comment line."""
    entries = []
    for number, line in enumerate(Path(path).read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        if len(parts) < 2:
            raise UserError(f"{path}:{number}: expected 'timestamp filename', got {line!r}")
        entries.append((float(parts[0]), parts[1]))
    return entries


def associate(
    first: list[float], second: list[float], max_difference: float = MAX_DIFFERENCE_S
) -> list[tuple[int, int]]:
    """Match timestamps one-to-one, closest pairs first, as TUM's associate.py does.

    Returns index pairs (i, j) sorted by ``first[i]``; each side is used at most once
    and no pair is further apart than ``max_difference`` seconds.
    """
    order = sorted(range(len(second)), key=second.__getitem__)
    sorted_second = [second[j] for j in order]
    candidates = []
    for i, t in enumerate(first):
        lo = bisect.bisect_left(sorted_second, t - max_difference)
        hi = bisect.bisect_right(sorted_second, t + max_difference)
        candidates.extend((abs(t - sorted_second[k]), i, order[k]) for k in range(lo, hi))
    candidates.sort()
    used_first: set[int] = set()
    used_second: set[int] = set()
    pairs = []
    for _, i, j in candidates:
        if i not in used_first and j not in used_second:
            used_first.add(i)
            used_second.add(j)
            pairs.append((i, j))
    return sorted(pairs, key=lambda p: first[p[0]])


def camera_for(root: Path) -> Intrinsics:
    """The sensor's calibration from the sequence name; fr3 (the paper's) otherwise."""
    for key, intrinsics in TUM_CAMERAS.items():
        if key in Path(root).resolve().name:
            return intrinsics
    return TUM_CAMERAS["freiburg3"]


class TumReader(PairsReader):
    """A TUM RGB-D sequence folder containing rgb.txt, depth.txt and the images."""

    def __init__(self, root: Path):
        self.root = Path(root)
        rgb = read_file_list(self.root / "rgb.txt")
        depth = read_file_list(self.root / "depth.txt")
        matches = associate([t for t, _ in rgb], [t for t, _ in depth])
        if not matches:
            raise UserError(f"{self.root}: no rgb/depth pair within {MAX_DIFFERENCE_S * 1000:.0f} ms")
        self.intrinsics = camera_for(self.root)
        pairs = [
            RecordedPair(
                f"{rgb[i][0]:.6f}",
                self.root / rgb[i][1],
                self.root / depth[j][1],
                DEPTH_UNITS_PER_METRE,
                self.intrinsics,
            )
            for i, j in matches
        ]
        super().__init__(self.root.name, LICENCE, pairs)
