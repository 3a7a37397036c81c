"""The one place recording formats are told apart and opened, for ``train``, ``evaluate`` and ``fit`` alike.

Every format is listed as colour/depth file pairs (a ``PairsReader``): the layouts on
disk as they are, and bags and phone exports after their frames are written out as
files (depth already moved into the colour camera). Only NYU's ``.mat`` is read as
arrays where no folder to write to is given. ``fit`` keeps the pairs and writes its
splits as CSV manifests, so the split is a file anyone can open; ``train`` and
``evaluate`` read a config's ``DataSource`` through the same ``open_pairs``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from PIL import Image

from contract.errors import UserError
from recordings.azure_kinect import KinectOptions, is_kinect_recording, read_kinect
from recordings.folders import CameraFile, FoldersReader, colour_folder, is_folders_layout
from recordings.frames import DEFAULT_MAX_FRAMES, PairsReader, RecordedPair, kept_note, spread
from recordings.manifest import ManifestReader
from recordings.nyu import NyuReader
from recordings.phone_options import DEFAULT_MIN_CONFIDENCE, PhoneOptions
from recordings.record3d import is_record3d, read_record3d
from recordings.rosbag import DEFAULT_MAX_GAP_S, BagOptions, is_bag, read_bag
from recordings.sevenscenes import SevenScenesReader
from recordings.strayscanner import is_stray_scanner, read_stray_scanner
from recordings.tum import TumReader

FORMATS = ("folders", "tum", "7scenes", "nyu", "csv", "rosbag", "azurekinect", "strayscanner", "record3d")
#: Formats whose reader writes frames out as files before they can be listed.
WRITTEN = ("rosbag", "azurekinect", "strayscanner", "record3d")


@dataclass(frozen=True)
class ReadOptions:
    """How to read a recording beyond its layout: the camera, a bag's topics and pairing, thinning.

    ``None`` is "not given": each format's reader has its own default, and an option given for a
    format that has no use for it is refused (``refuse_unused``) rather than silently ignored.
    """

    camera: CameraFile = field(default_factory=CameraFile)
    color_topic: str | None = None
    depth_topic: str | None = None
    max_gap_s: float | None = None
    min_confidence: int | None = None
    every: int = 1
    #: At most this many pairs, evenly spread (None or 0: all); readers that write frames write only these.
    max_frames: int | None = DEFAULT_MAX_FRAMES


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
    #: The colour camera's frame, where the recording names one (a bag's CameraInfo header).
    frame_id: str | None = None


def detect_format(root: Path) -> str:
    """The layout of ``root``, or a ValueError that says what was found and what was expected."""
    root = Path(root)
    if not root.exists():
        raise UserError(f"{root}: no such file or folder")
    if is_bag(root):
        return "rosbag"
    if is_kinect_recording(root):
        return "azurekinect"
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
            f"{root}: a file, but not a .csv manifest, an NYU .mat, a ROS bag (.bag, .mcap, .db3), an Azure Kinect "
            ".mkv or a Record3D .r3d"
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
        "files, a ROS 2 bag folder (metadata.yaml), a Stray Scanner export (rgb.mp4, depth/, camera_matrix.csv), "
        "a Record3D .r3d, an Azure Kinect .mkv, a .csv manifest or an NYU .mat; or pass --format"
    )


def open_pairs(root: Path, format: str, options: ReadOptions, scratch: Path | None) -> PairsReader:
    """The pairs of the recording at ``root``; ``options.camera`` overrides its intrinsics and depth scale.

    ``scratch`` is where a bag's, a phone export's and NYU's frames are written out as files.
    """
    root = Path(root)
    if format not in FORMATS:
        raise UserError(f"format {format!r}: expected one of {', '.join(FORMATS)}")
    if scratch is None and (format in WRITTEN or format == "nyu"):
        raise UserError(f"{root}: {format} frames are written out before training; fit one with rgb2cloud fit")
    refuse_unused(root, format, options)
    if format in WRITTEN:
        reader = _written(root, format, options, Path(scratch) / f"{format}-frames")
    elif format == "folders":
        reader = FoldersReader(root, options.camera)
    elif format == "csv":
        reader = ManifestReader(root)
    elif format == "tum":
        reader = TumReader(root)
    elif format == "7scenes":
        reader = SevenScenesReader(root)
    else:
        reader = _nyu_files(root, Path(scratch) / "nyu-frames")
    if format not in ("folders", *WRITTEN):  # folders merge with intrinsics.json; written readers take it first
        # NYU's frames are written out in millimetres whatever the recording's units were.
        camera = replace(options.camera, depth_scale=None) if format == "nyu" else options.camera
        reader.pairs = [_overridden(p, camera) for p in reader.pairs]
    return reader


#: The read options each format uses, by ``ReadOptions`` field and the flag that sets it.
FORMAT_OPTIONS = {
    "color_topic": ("--color-topic", ("rosbag",)),
    "depth_topic": ("--depth-topic", ("rosbag",)),
    "max_gap_s": ("--max-gap-ms", ("rosbag", "azurekinect")),
    "min_confidence": ("--min-confidence", ("strayscanner", "record3d")),
}


def refuse_unused(root: Path, format: str, options: ReadOptions) -> None:
    """A UserError for the first option given that ``format``'s reader has no use for."""
    for key, (flag, formats) in FORMAT_OPTIONS.items():
        if getattr(options, key) is not None and format not in formats:
            raise UserError(f"{root}: {flag} does not apply to a {format} recording (only to {', '.join(formats)})")


def open_recording(root: Path, format: str | None, options: ReadOptions, scratch: Path) -> Recording:
    """Every ``options.every``-th pair of the recording at ``root``, in any of ``FORMATS`` (detected if None)."""
    root = Path(root)
    format = format or detect_format(root)
    reader = open_pairs(root, format, options, scratch)
    pairs, notes = reader.pairs, list(reader.notes)
    if format not in WRITTEN:  # written readers thin before they write
        kept = spread(pairs[:: options.every], options.max_frames)
        if len(kept) < len(pairs):
            notes.append(kept_note(len(pairs), len(kept), options.every, options.max_frames, "pairs"))
        pairs = kept
    return Recording(root, format, pairs, reader.skipped, reader.licence or None, notes, reader.frame_id)


def _overridden(pair: RecordedPair, camera: CameraFile) -> RecordedPair:
    """``pair`` with every intrinsic and the depth scale that ``camera`` sets."""
    k = pair.camera
    own = CameraFile.of(k, pair.depth_scale)
    merged = own.merged(camera)
    if merged == own:
        return pair
    return replace(pair, camera=merged.intrinsics(k.width, k.height, pair.rgb), depth_scale=merged.depth_scale)


def _written(root: Path, format: str, options: ReadOptions, out: Path) -> PairsReader:
    """A recording whose reader writes its frames out first: a ROS bag, an Azure Kinect recording, a Stray
    Scanner or Record3D export.

    ``options.camera`` goes to the reader, which applies it to the recording's own camera (in the pixels of
    the images as recorded) before it registers, resizes or writes anything.
    """
    gap = DEFAULT_MAX_GAP_S if options.max_gap_s is None else options.max_gap_s
    if format == "rosbag":
        topics = (options.color_topic, options.depth_topic)
        return read_bag(root, out, BagOptions(*topics, gap, options.every, options.max_frames, options.camera))
    if options.camera.depth_scale is not None:
        raise UserError(f"{root}: --depth-scale does not apply to a {format} recording: its format fixes the units")
    if format == "azurekinect":
        return read_kinect(root, out, KinectOptions(gap, options.every, options.max_frames, options.camera))
    read = read_stray_scanner if format == "strayscanner" else read_record3d
    confidence = DEFAULT_MIN_CONFIDENCE if options.min_confidence is None else options.min_confidence
    return read(root, out, PhoneOptions(options.every, options.max_frames, confidence, options.camera))


def _nyu_files(root: Path, folder: Path) -> PairsReader:
    """NYU's frames written out as a colour PNG and a millimetre depth PNG each (once)."""
    reader = NyuReader(root, "all")
    folder.mkdir(parents=True, exist_ok=True)
    pairs = []
    for i in range(len(reader)):
        rgb, depth = folder / f"{i:05d}.png", folder / f"{i:05d}.depth.png"
        frame = reader[i]
        if not depth.exists():
            Image.fromarray(frame.rgb).save(rgb)
            Image.fromarray(np.clip(np.rint(frame.depth * 1000), 0, 65535).astype(np.uint16)).save(depth)
        pairs.append(RecordedPair(f"{i:05d}", rgb, depth, 1000.0, frame.intrinsics))
    return PairsReader(reader.name, reader.licence, pairs)
