"""A recording of one place, whatever layout it came in, as colour/depth file pairs in time order.

``fit`` writes its splits as CSV manifests of these pairs (``trainer.data.manifest``),
so the trainer reads every layout the same way and the split is a file anyone can open.
NYU's ``.mat`` and ROS bags hold arrays and messages, not files: their frames are written
out as images first (a bag's depth already moved into its colour camera).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from PIL import Image

from contract.errors import UserError
from trainer.data.folders import CameraFile, colour_folder, find_pairs, is_folders_layout, read_intrinsics_json
from trainer.data.manifest import COLUMNS, ManifestReader
from trainer.data.nyu import NyuReader
from trainer.data.record3d import is_record3d, read_record3d
from trainer.data.rosbag import DEFAULT_MAX_GAP_S, DEPTH_SCALE, is_bag, read_bag
from trainer.data.sevenscenes import SevenScenesReader
from trainer.data.strayscanner import DEFAULT_MIN_CONFIDENCE, is_stray_scanner, read_stray_scanner
from trainer.data.tum import DEPTH_UNITS_PER_METRE, TumReader

FORMATS = ("folders", "tum", "7scenes", "nyu", "csv", "rosbag", "strayscanner", "record3d")


@dataclass(frozen=True)
class RecordedPair:
    """One colour/depth pair on disk, with its depth units and camera."""

    name: str
    rgb: Path
    depth: Path
    depth_scale: float
    fx: float
    fy: float
    cx: float
    cy: float


@dataclass
class Recording:
    """The pairs of one recording in time order, what was skipped and why, and where it came from."""

    root: Path
    format: str
    pairs: list[RecordedPair]
    skipped: list[tuple[str, str]]
    licence: str | None
    #: What the reader found that a user should see (a bag's topics, rates, pairing gaps, registration).
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class ReadOptions:
    """How to read a recording beyond its layout: the camera, a bag's topics and pairing, thinning."""

    camera: CameraFile = field(default_factory=CameraFile)
    color_topic: str | None = None
    depth_topic: str | None = None
    max_gap_s: float = DEFAULT_MAX_GAP_S
    min_confidence: int = DEFAULT_MIN_CONFIDENCE
    every: int = 1


def detect_format(root: Path) -> str:
    """The layout of ``root``, or a ValueError that says what was found and what was expected."""
    root = Path(root)
    if not root.exists():
        raise UserError(f"{root}: no such file or folder")
    if is_bag(root):
        return "rosbag"
    if is_stray_scanner(root):
        return "strayscanner"
    if is_record3d(root):
        return "record3d"
    if root.is_file():
        if root.suffix == ".csv":
            return "csv"
        if root.suffix == ".mat":
            return "nyu"
        raise UserError(
            f"{root}: a file, but not a .csv manifest, an NYU .mat, a ROS bag (.bag, .mcap, .db3) or a Record3D .r3d"
        )
    if is_folders_layout(root):
        return "folders"
    if (colours := colour_folder(root)) is not None:
        raise UserError(
            f"{root}: {colours.name}/ but no depth/ folder: fit needs depth images (16-bit PNG) beside the photos"
        )
    if (root / "rgb.txt").is_file() and (root / "depth.txt").is_file():
        return "tum"
    if any(root.glob("frame-*.color.*")):
        return "7scenes"
    found = sorted(p.name + ("/" if p.is_dir() else "") for p in root.iterdir())[:8]
    raise UserError(
        f"{root}: cannot tell its layout (found {', '.join(found) or 'nothing'}); expected color/ (or rgb/, "
        "image/) and depth/ folders, a TUM sequence (rgb.txt, depth.txt), 7-Scenes frame-NNNNNN.color.jpg "
        "files, a ROS 2 bag folder (metadata.yaml), a .csv manifest or an NYU .mat; or pass --format"
    )


def open_recording(root: Path, format: str | None, options: ReadOptions, scratch: Path) -> Recording:
    """Every ``options.every``-th pair of the recording at ``root``; ``options.camera`` overrides its
    intrinsics and depth scale.

    ``scratch`` is where NYU's and a bag's frames are written out as files.
    """
    root = Path(root)
    format = format or detect_format(root)
    if format not in FORMATS:
        raise UserError(f"--format {format!r}: expected one of {', '.join(FORMATS)}")
    if format in ("rosbag", "strayscanner", "record3d"):
        return _written(root, format, options, scratch)
    recording = _open(root, format, options.camera, scratch)
    if options.every > 1:
        recording.pairs = recording.pairs[:: options.every]
        recording.notes.append(f"every {options.every}th pair kept: {len(recording.pairs)}")
    return recording


def _open(root: Path, format: str, camera: CameraFile, scratch: Path) -> Recording:
    if format == "folders":
        return _folders(root, camera)
    if format == "csv":
        reader = ManifestReader(root)
        base = reader.path.parent
        pairs = [
            _pair(Path(rgb).stem, base / rgb, base / depth, CameraFile(**numbers).merged(camera), root)
            for rgb, depth, numbers in reader.rows
        ]
        return Recording(root, format, pairs, [], None)
    if format == "tum":
        reader = TumReader(root)
        k = reader.intrinsics
        own = CameraFile(k.fx, k.fy, k.cx, k.cy, DEPTH_UNITS_PER_METRE).merged(camera)
        pairs = [_pair(f"{t:.6f}", root / rgb, root / depth, own, root) for (t, rgb), (_, depth) in reader.pairs]
        return Recording(root, format, pairs, [], reader.licence)
    if format == "7scenes":
        reader = SevenScenesReader(root)
        k = reader.intrinsics
        own = CameraFile(k.fx, k.fy, k.cx, k.cy, 1000.0).merged(camera)
        pairs = [
            _pair(f"{n:06d}", path, path.with_name(f"frame-{n:06d}.depth.png"), own, root)
            for n, path in zip(reader.frame_numbers, reader.colour_paths, strict=True)
        ]
        return Recording(root, format, pairs, [], reader.licence)
    return _nyu(root, camera, scratch)


def _pair(name: str, rgb: Path, depth: Path, camera: CameraFile, root: Path) -> RecordedPair:
    missing = [key for key in ("fx", "fy", "cx", "cy") if getattr(camera, key) is None]
    if missing:
        raise UserError(
            f"{root}: no camera intrinsics ({', '.join(missing)} missing): add an intrinsics.json "
            "(Open3D's PinholeCameraIntrinsic, or fx, fy, cx, cy) or pass --fx --fy --cx --cy"
        )
    scale = camera.depth_scale if camera.depth_scale is not None else 1000.0
    return RecordedPair(name, rgb.resolve(), depth.resolve(), scale, camera.fx, camera.fy, camera.cx, camera.cy)


def _written(root: Path, format: str, options: ReadOptions, scratch: Path) -> Recording:
    """A recording whose reader writes its frames out first: a ROS bag, a Stray Scanner or Record3D export."""
    out = scratch / f"{format}-frames"
    if format == "rosbag":
        written = read_bag(root, out, options.color_topic, options.depth_topic, options.max_gap_s, options.every)
    else:
        read = read_stray_scanner if format == "strayscanner" else read_record3d
        written = read(root, out, options.every, options.min_confidence)
    k = CameraFile(written.camera.fx, written.camera.fy, written.camera.cx, written.camera.cy, None)
    k = k.merged(options.camera)
    own = CameraFile(k.fx, k.fy, k.cx, k.cy, DEPTH_SCALE)  # the frames were written in millimetres
    pairs = [_pair(name, rgb, depth, own, root) for name, rgb, depth in written.pairs]
    return Recording(root, format, pairs, written.skipped, None, written.notes)


def _folders(root: Path, camera: CameraFile) -> Recording:
    pairs, skipped = find_pairs(root)
    if not pairs:
        raise UserError(f"{root}: no colour image has a depth image ({len(skipped)} colour images, none paired)")
    intrinsics = root / "intrinsics.json"
    own = read_intrinsics_json(intrinsics).merged(camera) if intrinsics.is_file() else camera
    return Recording(root, "folders", [_pair(p.name, p.rgb, p.depth, own, root) for p in pairs], skipped, None)


def _nyu(root: Path, camera: CameraFile, scratch: Path) -> Recording:
    reader = NyuReader(root, "all")
    folder = scratch / "nyu-frames"
    folder.mkdir(parents=True, exist_ok=True)
    pairs = []
    for i in range(len(reader)):
        frame = reader[i]
        rgb, depth = folder / f"{i:05d}.png", folder / f"{i:05d}.depth.png"
        if not depth.exists():
            Image.fromarray(frame.rgb).save(rgb)
            Image.fromarray(np.clip(np.rint(frame.depth * 1000), 0, 65535).astype(np.uint16)).save(depth)
        k = frame.intrinsics
        own = CameraFile(k.fx, k.fy, k.cx, k.cy, 1000.0).merged(replace(camera, depth_scale=None))
        pairs.append(_pair(f"{i:05d}", rgb, depth, own, root))
    return Recording(root, "nyu", pairs, [], reader.licence)


def write_manifest(path: Path, pairs: list[RecordedPair]) -> Path:
    """A CSV manifest of ``pairs`` with absolute paths, as ``trainer.data.manifest`` reads it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        for p in pairs:
            writer.writerow([p.rgb, p.depth, p.depth_scale, p.fx, p.fy, p.cx, p.cy])
    return path
