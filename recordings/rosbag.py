"""ROS bags as colour/depth pairs in the colour camera: ROS 1 ``.bag``, ROS 2 sqlite3 and MCAP.

What robot teams and RealSense owners record. ``rosbags``' ``AnyReader`` reads every kind
without a ROS install, with message types from the bag itself. A bag holds streams, not
pairs, so this reader:

1. finds the colour and depth image topics (``sensor_msgs/Image`` or ``CompressedImage``,
   told apart by their encodings; depth already aligned to colour is preferred) and the
   ``CameraInfo`` beside each, unless ``color_topic`` / ``depth_topic`` name them;
2. pairs each colour frame with the depth frame nearest in time (header stamps), within
   ``max_gap_s``; colour frames with none are skipped with the gap that was found;
3. moves depth into the colour camera when it is not there already, with the rigid
   transform the bag stores (``recordings.rosbag_extrinsics``). With none, only the two
   cameras' intrinsics are used, and the reader says so;
4. writes each pair out at the size fit trains at (``PairWriter``: a compressed photo already that size as
   stored, others as JPEG; depth as 16-bit millimetres),
   so the rest of ``fit`` reads a bag like any other recording.

Depth units: ``16UC1`` / ``mono16`` are millimetres (REP 118) unless a RealSense "Depth
Units" option in the bag says otherwise; ``32FC1`` is metres.
"""

from __future__ import annotations

import statistics
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from contract.errors import UserError
from recordings.folders import CameraFile
from recordings.frames import DEFAULT_MAX_FRAMES, PairsReader, kept_note, nearest_stamp, spread
from recordings.pair_writer import PairWriter, damaged_note, written_pairs
from recordings.registration import reproject_depth
from recordings.rosbag_cameras import Geometry, bag_geometry, is_rectified, same_camera
from recordings.rosbag_damage import damage
from recordings.rosbag_extrinsics import depth_to_colour_extrinsics
from recordings.rosbag_images import (
    COLOUR_ENCODINGS,
    COMPRESSED,
    DEPTH_ENCODINGS,
    FRAME_DAMAGE,
    IMAGE,
    Stream,
    colour_image,
    decoded,
    depth_image,
    frame_damage,
    message_size,
)

CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
#: Colour and depth stamped further apart than this are not a pair (a 30 fps stream's frames are 33 ms apart).
DEFAULT_MAX_GAP_S = 0.02


def is_bag(path: Path) -> bool:
    """A ROS 1 bag, an MCAP file, or a ROS 2 bag folder (``metadata.yaml`` with its storage files)."""
    path = Path(path)
    if path.is_file():
        return path.suffix in (".bag", ".mcap", ".db3")
    return (path / "metadata.yaml").is_file()


def _bag_path(path: Path) -> Path:
    """What ``AnyReader`` opens: a ROS 1 file, or a ROS 2 bag's folder (also when given its .db3 or .mcap)."""
    path = Path(path)
    if path.is_file() and path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        return path.parent
    return path


@dataclass(frozen=True)
class BagOptions:
    """Which topics, how close in time a pair must be, which colour frames to keep, and camera overrides.

    ``camera`` (``--fx`` ... ``--depth-scale``) is applied to the colour camera's CameraInfo, in the
    pixels of its images, and to the depth units, before any frame is registered or written.
    """

    color_topic: str | None = None
    depth_topic: str | None = None
    max_gap_s: float = DEFAULT_MAX_GAP_S
    every: int = 1
    max_frames: int | None = DEFAULT_MAX_FRAMES
    camera: CameraFile = field(default_factory=CameraFile)


def read_bag(path: Path, out_dir: Path, options: BagOptions | None = None) -> PairsReader:
    """The bag's colour frames with their nearest depth, depth in the colour camera, written under ``out_dir``.

    A bag damaged in any byte (a recorder killed mid-write, a disk error) is one line that names the bag
    and what is wrong, in words. Only what the bag libraries raise for damaged bytes is caught: a bug
    in this reader keeps its traceback.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    options = options or BagOptions()
    source = _bag_path(path)
    try:
        with AnyReader([source], default_typestore=get_typestore(Stores.LATEST)) as reader:
            return _read(reader, Path(path), Path(out_dir), options)
    except UserError:
        raise
    except Exception as e:
        if (words := damage(e)) is None:  # not damage: a bug, or a failed write, keeps its traceback
            raise
        raise UserError(f"{path}: {words}") from None


def _read(reader: Any, path: Path, out: Path, options: BagOptions) -> PairsReader:
    streams = _streams(reader)
    colour = _choose(path, streams, options.color_topic, "colour", ("color", "colour", "rgb"))
    depth = _choose(path, streams, options.depth_topic, "depth", ("aligned_depth_to_color", "depth"))
    (colour_topic, colour_info), (depth_topic, depth_info) = (_camera_info(reader, path, s) for s in (colour, depth))
    camera_notes: list[str] = []
    units = _depth_units_m(path, reader, depth, options.camera.depth_scale)
    topics = sorted({(c.topic, c.msgtype) for c in reader.connections})
    frames = (depth_info.header.frame_id, colour_info.header.frame_id)
    read = partial(_topic_messages, reader)
    geometry, how = bag_geometry(
        path,
        (colour, colour_topic, colour_info),
        (depth, depth_topic, depth_info),
        options.camera,
        units,
        lambda: depth_to_colour_extrinsics(read, topics, depth.topic, colour.topic, *frames),
        camera_notes,
    )
    stamps = {s.topic: _stamps(reader, s.topic) for s in (colour, depth)}
    every = list(enumerate(stamps[colour.topic]))[:: max(1, options.every)]
    colour_stamps = dict(spread(every, options.max_frames))
    matches, skipped = _pair(colour_stamps, stamps[depth.topic], options.max_gap_s)
    if not matches:
        nearest = min((why for _, why in skipped), default="no colour frames", key=len)
        raise UserError(
            f"{path}: no colour frame of {colour.topic} has depth from {depth.topic} within "
            f"{options.max_gap_s * 1000:.0f} ms ({len(colour_stamps)} colour, {len(stamps[depth.topic])} depth "
            f"frames; e.g. {nearest}); pass --max-gap-ms to allow more"
        )
    writer = PairWriter(out, geometry.colour.camera.width, geometry.colour.camera.height)
    pairs, damaged, stamps_ns = _write_pairs(reader, writer, colour, depth, matches, geometry)
    gaps_ms = [abs(c - d) * 1000 for c, d in matches.values()]
    total = len(stamps[colour.topic])
    notes = [
        f"bag: colour {colour.topic} ({colour.encoding}, {colour.count} frames{_rate(stamps[colour.topic])}), "
        f"depth {depth.topic} ({depth.encoding}, {depth.count} frames{_rate(stamps[depth.topic])}), "
        f"depth unit {geometry.units_m * 1000:g} mm",
        f"paired within {options.max_gap_s * 1000:.0f} ms: {len(matches)} of {len(colour_stamps)} colour frames, "
        f"gap median {statistics.median(gaps_ms):.1f} ms, max {max(gaps_ms):.1f} ms",
        f"registration: {how}; written at {writer.size[0]}x{writer.size[1]}",
        *camera_notes,
    ]
    if len(colour_stamps) < total:
        notes.append(kept_note(total, len(colour_stamps), options.every, options.max_frames))
    if damaged:
        notes.append(damaged_note(damaged))
    camera = writer.camera(geometry.colour.camera)
    return written_pairs(path.name, pairs, camera, skipped + damaged, notes, stamps_ns, colour_info.header.frame_id)


def _streams(reader: Any) -> list[Stream]:
    """Every image topic with the encoding and size of its first message."""
    found = []
    for topic in sorted({c.topic for c in reader.connections if c.msgtype in (IMAGE, COMPRESSED)}):
        connections = [c for c in reader.connections if c.topic == topic]
        for connection, _, raw in reader.messages(connections=connections):
            message = reader.deserialize(raw, connection.msgtype)
            encoding = message.encoding if connection.msgtype == IMAGE else message.format
            width, height = message_size(message, connection.msgtype)
            count = sum(c.msgcount for c in connections)
            found.append(Stream(topic, connection.msgtype, count, encoding, width, height))
            break
    return found


def _choose(path: Path, streams: list[Stream], wanted: str | None, kind: str, preferred: tuple[str, ...]) -> Stream:
    """The stream ``wanted`` names (checked to be of this kind), else the one whose name is most preferred.

    Among equally named candidates a rectified topic (``image_rect``) wins over a raw one: its lens
    distortion is already undone.
    """
    flag = "--color-topic" if kind == "colour" else "--depth-topic"
    fits = (lambda s: s.is_colour) if kind == "colour" else (lambda s: s.is_depth)
    if wanted is not None:
        named = [s for s in streams if s.topic == wanted]
        if not named:
            listed = ", ".join(s.topic for s in streams) or "none"
            raise UserError(f"{path}: no image topic {wanted!r} (image topics: {listed})")
        if not fits(named[0]):
            other = "depth" if named[0].is_depth else "colour" if named[0].is_colour else "of an unsupported kind"
            raise UserError(
                f"{path}: {flag} {wanted}: its images are {other} ({named[0].encoding}), not {kind}; colour is one "
                f"of {', '.join(COLOUR_ENCODINGS)} or compressed, depth one of {', '.join(DEPTH_ENCODINGS)} or "
                "compressedDepth"
            )
        return named[0]
    candidates = [s for s in streams if fits(s)]
    if not candidates:
        listed = ", ".join(f"{s.topic} ({s.encoding})" for s in streams) or "none"
        raise UserError(f"{path}: no {kind} image topic (image topics: {listed}); pass {flag}")
    for word in preferred:
        named = [s for s in candidates if word in s.topic.lower()]
        if len(named) == 1:
            return named[0]
        if named:
            candidates = named
            break
    rectified = [s for s in candidates if is_rectified(s.topic)]
    if len(rectified) == 1:
        return rectified[0]
    if len(candidates) > 1:
        listed = ", ".join(s.topic for s in candidates)
        raise UserError(f"{path}: several {kind} topics ({listed}); pass {flag}")
    return candidates[0]


def _camera_info(reader: Any, path: Path, stream: Stream) -> Any:
    """The CameraInfo message beside an image topic: the one whose topic shares the most of its path."""
    infos = [c for c in reader.connections if c.msgtype == CAMERA_INFO]
    parts = stream.topic.strip("/").split("/")

    def shared(topic: str) -> int:
        other = topic.strip("/").split("/")
        n = 0
        while n < min(len(parts), len(other)) and parts[n] == other[n]:
            n += 1
        return n

    best = max(infos, key=lambda c: shared(c.topic), default=None)
    if best is None or shared(best.topic) == 0:
        raise UserError(f"{path}: no CameraInfo for {stream.topic}: record its camera_info topic too")
    for connection, _, raw in reader.messages(connections=[best]):
        return best.topic, reader.deserialize(raw, connection.msgtype)
    raise UserError(f"{path}: {best.topic} holds no CameraInfo message")


def _stamp(message: Any, bag_ns: int) -> float:
    """Seconds: the header's stamp, or the bag's receive time where the header has none."""
    return _stamp_ns(message, bag_ns) * 1e-9


def _stamp_ns(message: Any, bag_ns: int) -> int:
    """Nanoseconds, exactly: the header's stamp, or the bag's receive time where the header has none."""
    header = getattr(message, "header", None)
    if header is not None and (header.stamp.sec or header.stamp.nanosec):
        return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
    return bag_ns


def _messages(reader: Any, topic: str) -> Iterator[tuple[Any, int, Any]]:
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:  # an empty list would mean every topic to rosbags
        return
    for connection, bag_ns, raw in reader.messages(connections=connections):
        yield connection, bag_ns, reader.deserialize(raw, connection.msgtype)


def _topic_messages(reader: Any, topic: str) -> Iterator[Any]:
    return (message for _, _, message in _messages(reader, topic))


def _stamps(reader: Any, topic: str) -> list[float]:
    return [_stamp(message, bag_ns) for _, bag_ns, message in _messages(reader, topic)]


def _rate(stamps: list[float]) -> str:
    if len(stamps) < 2 or stamps[-1] <= stamps[0]:
        return ""
    return f", {(len(stamps) - 1) / (stamps[-1] - stamps[0]):.1f} fps"


def _pair(
    colour: dict[int, float], depth: list[float], max_gap_s: float
) -> tuple[dict[int, tuple[float, float]], list[tuple[str, str]]]:
    """Colour message index -> (its stamp, the nearest depth stamp) within ``max_gap_s``; the frames skipped."""
    matches, skipped = {}, []
    ordered = np.sort(np.asarray(depth))
    for i, t in colour.items():
        found = nearest_stamp(ordered, t)
        if found is not None and found[1] <= max_gap_s:
            matches[i] = (t, float(ordered[found[0]]))
        else:
            gap = "no depth frames" if found is None else f"nearest depth {found[1] * 1000:.0f} ms away"
            skipped.append((f"{t:.6f}", gap))
    return matches, skipped


def _depth_units_m(path: Path, reader: Any, depth: Stream, depth_scale: float | None) -> float:
    """Metres per raw unit: ``--depth-scale``, else a RealSense "Depth Units" option in the depth sensor's
    namespace, else REP 118 (millimetres); float depth is metres, and a depth scale for it is refused."""
    if "32FC1" in depth.encoding:
        if depth_scale is not None:
            raise UserError(f"{path}: --depth-scale: {depth.topic} holds 32FC1 depth, which is metres by definition")
        return 1.0
    if depth_scale is not None:
        return 1.0 / depth_scale
    sensor = depth.topic.split("/")[:3]  # /device_0/sensor_N
    option = "/".join([*sensor, "option", "Depth Units", "value"])
    for _, _, message in _messages(reader, option):
        return float(message.data)
    return 0.001


def _write_pairs(
    reader: Any,
    writer: PairWriter,
    colour: Stream,
    depth: Stream,
    matches: dict[int, tuple[float, float]],
    geometry: Geometry,
) -> tuple[list[tuple[str, Path, Path]], list[tuple[str, str]], dict[str, int]]:
    """Write each matched pair: the photo undistorted, depth registered to it, both at the written size.

    Photos are written in a first pass and depth in a second, so no frame waits in memory for its partner.
    Returns the pairs written, the damaged ones skipped with why, and each photo's stamp in nanoseconds.
    """
    wanted_colour = {i: f"{c:.6f}" for i, (c, _) in matches.items()}
    wanted_depth: dict[float, list[str]] = {}
    for i, (_, d) in matches.items():
        wanted_depth.setdefault(d, []).append(wanted_colour[i])
    colour_files: dict[str, Path] = {}
    damaged: dict[str, str] = {}
    index = -1
    stamps: dict[str, int] = {}
    for connection, bag_ns, message in _messages(reader, colour.topic):
        index += 1
        name = wanted_colour.get(index)
        if name is None:
            continue
        try:
            stored = colour_image(message, connection.msgtype)
            pixels = decoded(stored)
        except FRAME_DAMAGE as e:
            damaged[name] = f"colour frame {frame_damage(e)}"
            continue
        stamps[name] = _stamp_ns(message, bag_ns)
        if geometry.colour.model is not None:
            colour_files[name] = writer.photo(name, geometry.colour.undistorted(pixels, nearest=False))[0]
        else:
            colour_files[name] = writer.photo(name, pixels, stored if isinstance(stored, bytes) else None)[0]
    written = writer.camera(geometry.colour.camera)
    for connection, bag_ns, message in _messages(reader, depth.topic):
        names = [name for name in wanted_depth.get(_stamp(message, bag_ns), []) if name not in damaged]
        if not names:
            continue
        try:
            metres = geometry.depth.undistorted(depth_image(message, connection.msgtype, geometry.units_m), True)
        except FRAME_DAMAGE as e:
            damaged.update({name: f"depth frame {frame_damage(e)}" for name in names})
            continue
        if not (geometry.aligned and same_camera(geometry.depth.camera, written)):
            g = geometry
            metres = reproject_depth(metres, g.depth.camera, written, g.rotation, g.translation)
        for name in names:
            writer.depth(name, metres)
    files = [
        (name, colour_files[name], writer.out / "depth" / f"{name}.png")
        for name in wanted_colour.values()
        if name not in damaged
    ]
    return files, sorted(damaged.items()), stamps
