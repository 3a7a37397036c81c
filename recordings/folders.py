"""The layout most RGB-D recorders write: a folder of colour images and a folder of 16-bit depth images.

    my-room/
      color/   (or rgb/, image/)   000001.jpg, 000002.jpg, ...   or 1623456789.123456.png, ...
      depth/                       000001.png, 000002.png, ...   16-bit, depth_scale units per metre
      intrinsics.json              Open3D's PinholeCameraIntrinsic, or {"fx", "fy", "cx", "cy"}

Pairs match by file stem. Where stems are timestamps that differ between the two
streams (a colour and a depth camera are rarely triggered together), an unmatched
colour image takes the depth image nearest in time, within a tolerance. Frames are
ordered by time: numerically where stems are numbers (``2.jpg`` before ``10.jpg``),
else by name. Intrinsics and ``depth_scale`` follow Open3D's vocabulary.
"""

from __future__ import annotations

import bisect
import fnmatch
import json
import re
from dataclasses import dataclass
from pathlib import Path

from contract.errors import UserError
from contract.geometry import Intrinsics
from recordings.frames import PairsReader, RecordedPair, image_size, parse_frame_ranges

COLOUR_FOLDERS = ("color", "rgb", "image")
DEPTH_FOLDER = "depth"
COLOUR_SUFFIXES = {".jpg", ".jpeg", ".png"}
DEPTH_SUFFIXES = {".png"}
INTRINSICS_FILE = "intrinsics.json"
#: Nearest-timestamp pairing tolerance, in the stems' own units (seconds for most recorders).
PAIR_TOLERANCE = 0.02


INTRINSIC_KEYS = ("fx", "fy", "cx", "cy")


@dataclass(frozen=True)
class CameraFile:
    """What ``intrinsics.json`` (and the command line) say about the camera and the depth units."""

    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    depth_scale: float | None = None

    @classmethod
    def of(cls, camera: Intrinsics, depth_scale: float | None = None) -> CameraFile:
        """A recording's own camera (and depth units), for the command line's values to override."""
        return cls(camera.fx, camera.fy, camera.cx, camera.cy, depth_scale)

    def merged(self, overrides: CameraFile) -> CameraFile:
        """These values with every value ``overrides`` sets taking precedence: the one way an override applies.

        Both are in the pixels of the same images, so a reader merges before it scales, crops or
        registers anything, and scales its own camera to the images first where they disagree.
        """
        pick = {k: v if v is not None else getattr(self, k) for k, v in vars(overrides).items()}
        return CameraFile(**pick)

    @property
    def sets_intrinsics(self) -> bool:
        return any(getattr(self, k) is not None for k in INTRINSIC_KEYS)

    def intrinsics(self, width: int, height: int, where: Path) -> Intrinsics:
        """The camera for a ``width`` x ``height`` photo; UserError naming ``where`` if a value is missing."""
        missing = [key for key in INTRINSIC_KEYS if getattr(self, key) is None]
        if missing:
            raise UserError(
                f"{where}: no camera intrinsics ({', '.join(missing)} missing): add an {INTRINSICS_FILE} "
                "(Open3D's PinholeCameraIntrinsic, or fx, fy, cx, cy) or pass --fx --fy --cx --cy"
            )
        return Intrinsics(self.fx, self.fy, self.cx, self.cy, width, height)


def read_intrinsics_json(path: Path) -> CameraFile:
    """Open3D's ``PinholeCameraIntrinsic`` JSON (``intrinsic_matrix`` column-major) or plain fx, fy, cx, cy."""
    try:
        data = json.loads(Path(path).read_text())
    except json.JSONDecodeError as e:
        raise UserError(f"{path}: not JSON: {e}") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a JSON object")
    scale = data.get("depth_scale")
    if "intrinsic_matrix" in data:
        k = data["intrinsic_matrix"]
        if not (isinstance(k, list) and len(k) == 9):
            raise UserError(f"{path}: intrinsic_matrix must hold 9 numbers (a 3x3 matrix, column-major)")
        return CameraFile(fx=float(k[0]), fy=float(k[4]), cx=float(k[6]), cy=float(k[7]), depth_scale=scale)
    if all(key in data for key in ("fx", "fy", "cx", "cy")):
        return CameraFile(*(float(data[key]) for key in ("fx", "fy", "cx", "cy")), depth_scale=scale)
    raise UserError(f"{path}: expected Open3D's intrinsic_matrix, or fx, fy, cx and cy")


@dataclass(frozen=True)
class PairFiles:
    """One colour image and the depth image that goes with it."""

    name: str
    rgb: Path
    depth: Path


def _number(stem: str) -> float | None:
    try:
        return float(stem)
    except ValueError:
        return None


def _time_key(stem: str) -> tuple:
    """Numbers in time order, names after them in natural order (``learn2`` before ``learn10``)."""
    number = _number(stem)
    if number is not None:
        return (0, number, "")
    parts = re.split(r"(\d+)", stem)
    return (1, 0.0, tuple(int(p) if p.isdigit() else p for p in parts))


def colour_folder(root: Path) -> Path | None:
    return next((root / name for name in COLOUR_FOLDERS if (root / name).is_dir()), None)


def is_folders_layout(root: Path) -> bool:
    return Path(root).is_dir() and colour_folder(Path(root)) is not None and (Path(root) / DEPTH_FOLDER).is_dir()


def find_pairs(root: Path, tolerance: float = PAIR_TOLERANCE) -> tuple[list[PairFiles], list[tuple[str, str]]]:
    """Every colour/depth pair in time order, and each colour image skipped with the reason."""
    root = Path(root)
    colours = colour_folder(root)
    if colours is None:
        raise UserError(f"{root}: no colour folder ({'/, '.join(COLOUR_FOLDERS)}/)")
    if not (root / DEPTH_FOLDER).is_dir():
        raise UserError(f"{root}: {colours.name}/ but no {DEPTH_FOLDER}/ folder: depth images go beside the photos")
    colour_files = {p.stem: p for p in colours.iterdir() if p.suffix.lower() in COLOUR_SUFFIXES}
    depth_files = {p.stem: p for p in (root / DEPTH_FOLDER).iterdir() if p.suffix.lower() in DEPTH_SUFFIXES}
    timed = sorted((t, stem) for stem in depth_files if (t := _number(stem)) is not None)
    times = [t for t, _ in timed]
    used: set[str] = set()
    pairs, skipped = [], []
    for stem in sorted(colour_files, key=_time_key):
        match = stem if stem in depth_files else None
        t = _number(stem)
        if match is None and t is not None and times:
            i = bisect.bisect_left(times, t)
            near = [j for j in (i - 1, i) if 0 <= j < len(times)]
            j = min(near, key=lambda j: abs(times[j] - t))
            if abs(times[j] - t) <= tolerance:
                match = timed[j][1]
        if match is None:
            skipped.append((stem, "no depth image with this name or within the time tolerance"))
        elif match in used:
            skipped.append((stem, f"its nearest depth image {match} is already paired"))
        else:
            used.add(match)
            pairs.append(PairFiles(stem, colour_files[stem], depth_files[match]))
    return pairs, skipped


def select_frames(names: list[str], spec: str) -> list[int]:
    """Indices of ``names`` (time order) matching comma-separated names, globs (``test*``) or index ranges."""
    chosen: set[int] = set()
    for item in (part.strip() for part in spec.split(",")):
        if not item:
            continue
        if item.replace("-", "").isdigit():
            indices = parse_frame_ranges(item)
            if indices[-1] >= len(names):
                raise UserError(f"frames {item}: the recording has frames 0-{len(names) - 1}")
            chosen.update(indices)
        else:
            hits = [i for i, name in enumerate(names) if fnmatch.fnmatch(name, item)]
            if not hits:
                raise UserError(f"frames {item!r} match no frame name (names look like {names[0]!r})")
            chosen.update(hits)
    return sorted(chosen)


class FoldersReader(PairsReader):
    """The pairs of a ``color/`` + ``depth/`` recording.

    ``camera`` fills in or overrides what ``intrinsics.json`` says; depth is in
    millimetres unless one of them gives ``depth_scale``.
    """

    def __init__(self, root: Path, camera: CameraFile | None = None):
        self.root = Path(root)
        found, skipped = find_pairs(self.root)
        if not found:
            raise UserError(
                f"{self.root}: no colour image has a depth image ({len(skipped)} colour images, none paired)"
            )
        own = self.root / INTRINSICS_FILE
        k = (read_intrinsics_json(own) if own.is_file() else CameraFile()).merged(camera or CameraFile())
        intrinsics = k.intrinsics(*image_size(found[0].rgb), self.root)
        scale = k.depth_scale or 1000.0
        pairs = [RecordedPair(p.name, p.rgb, p.depth, scale, intrinsics) for p in found]
        super().__init__(self.root.name, "", pairs, skipped)
