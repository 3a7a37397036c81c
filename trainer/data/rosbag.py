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
   transform the bag stores (``trainer.data.rosbag_extrinsics``). With none, only the two
   cameras' intrinsics are used, and the reader says so;
4. writes each pair out as files (colour as stored or PNG, depth as 16-bit millimetres),
   so the rest of ``fit`` reads a bag like any other recording.

Depth units: ``16UC1`` / ``mono16`` are millimetres (REP 118) unless a RealSense "Depth
Units" option in the bag says otherwise; ``32FC1`` is metres.
"""

from __future__ import annotations

import io
import statistics
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from contract.errors import UserError
from contract.geometry import Intrinsics
from trainer.data.frames import PairsReader, written_pairs
from trainer.data.rosbag_extrinsics import depth_to_colour_extrinsics
from trainer.registration import reproject_depth

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
COLOUR_ENCODINGS = {"rgb8": (3, False), "bgr8": (3, True), "rgba8": (4, False), "bgra8": (4, True), "mono8": (1, False)}
DEPTH_ENCODINGS = {"16UC1": np.uint16, "mono16": np.uint16, "32FC1": np.float32}
#: Colour and depth stamped further apart than this are not a pair (a 30 fps stream's frames are 33 ms apart).
DEFAULT_MAX_GAP_S = 0.02
#: Millimetres, what the pairs' depth files hold.
DEPTH_SCALE = 1000.0


@dataclass(frozen=True)
class Stream:
    """One image topic: its type, frame count, first message's encoding, and the CameraInfo beside it."""

    topic: str
    msgtype: str
    count: int
    encoding: str
    info_topic: str | None = None

    @property
    def is_depth(self) -> bool:
        return self.encoding in DEPTH_ENCODINGS or "compresseddepth" in self.encoding.lower()

    @property
    def is_colour(self) -> bool:
        if self.msgtype == COMPRESSED:
            return not self.is_depth and "depth" not in self.topic.lower()
        return self.encoding in COLOUR_ENCODINGS and not any(w in self.topic.lower() for w in ("infra", "/ir"))


@dataclass(frozen=True)
class Geometry:
    """How a depth frame becomes depth in the colour camera: both cameras, the rigid transform, the units."""

    depth_camera: Intrinsics
    colour_camera: Intrinsics
    rotation: np.ndarray
    translation: np.ndarray
    units_m: float

    @property
    def moves(self) -> bool:
        """Whether depth must be reprojected at all (not when it is already in the colour camera)."""
        identity = np.allclose(self.rotation, np.eye(3)) and np.allclose(self.translation, 0)
        return not (identity and _same_camera(self.depth_camera, self.colour_camera))


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


def read_bag(
    path: Path,
    out_dir: Path,
    color_topic: str | None = None,
    depth_topic: str | None = None,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    every: int = 1,
) -> PairsReader:
    """The bag's colour frames with their nearest depth, depth in the colour camera, written under ``out_dir``."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    source = _bag_path(path)
    try:
        with AnyReader([source], default_typestore=get_typestore(Stores.LATEST)) as reader:
            return _read(reader, Path(path), Path(out_dir), color_topic, depth_topic, max_gap_s, every)
    except AnyReaderError as e:
        raise UserError(f"{path}: not a readable ROS bag: {e}") from None


def _read(reader: Any, path: Path, out: Path, color_topic, depth_topic, max_gap_s, every) -> PairsReader:
    streams = _streams(reader)
    colour = _choose(path, streams, color_topic, "colour", lambda s: s.is_colour, ("color", "colour", "rgb"))
    depth = _choose(path, streams, depth_topic, "depth", lambda s: s.is_depth, ("aligned_depth_to_color", "depth"))
    colour_info, depth_info = (_camera_info(reader, path, s) for s in (colour, depth))
    colour_camera, depth_camera = (_intrinsics(info) for info in (colour_info, depth_info))
    stamps = {s.topic: _stamps(reader, s.topic) for s in (colour, depth)}
    colour_stamps = dict(list(enumerate(stamps[colour.topic]))[:: max(1, every)])
    matches, skipped = _pair(colour_stamps, stamps[depth.topic], max_gap_s)
    if not matches:
        nearest = min((why for _, why in skipped), default="no colour frames", key=len)
        raise UserError(
            f"{path}: no colour frame of {colour.topic} has depth from {depth.topic} within {max_gap_s * 1000:.0f} ms "
            f"({len(colour_stamps)} colour, {len(stamps[depth.topic])} depth frames; e.g. {nearest}); "
            "pass --max-gap-ms to allow more"
        )
    aligned = _same_camera(colour_camera, depth_camera) or "aligned_depth_to_color" in depth.topic
    transform, how = (np.eye(3), np.zeros(3)), "depth is aligned to colour in the bag"
    if not aligned:
        topics = sorted({(c.topic, c.msgtype) for c in reader.connections})
        frames = (depth_info.header.frame_id, colour_info.header.frame_id)
        read = partial(_topic_messages, reader)
        transform, how = depth_to_colour_extrinsics(read, topics, depth.topic, colour.topic, *frames)
    units = _depth_units_m(reader, depth)
    pairs = _write_pairs(reader, out, colour, depth, matches, Geometry(depth_camera, colour_camera, *transform, units))
    gaps_ms = [abs(c - d) * 1000 for c, d in matches.values()]
    notes = [
        f"bag: colour {colour.topic} ({colour.encoding}, {colour.count} frames{_rate(stamps[colour.topic])}), "
        f"depth {depth.topic} ({depth.encoding}, {depth.count} frames{_rate(stamps[depth.topic])}), "
        f"depth unit {units * 1000:g} mm",
        f"paired within {max_gap_s * 1000:.0f} ms: {len(matches)} of {len(colour_stamps)} colour frames"
        + (f" (every {every}th)" if every > 1 else "")
        + f", gap median {statistics.median(gaps_ms):.1f} ms, max {max(gaps_ms):.1f} ms",
        f"registration: {how}",
    ]
    return written_pairs(path.name, pairs, colour_camera, skipped, notes)


def _streams(reader: Any) -> list[Stream]:
    """Every image topic with the encoding of its first message."""
    found = []
    for topic in sorted({c.topic for c in reader.connections if c.msgtype in (IMAGE, COMPRESSED)}):
        connections = [c for c in reader.connections if c.topic == topic]
        for connection, _, raw in reader.messages(connections=connections):
            message = reader.deserialize(raw, connection.msgtype)
            encoding = message.encoding if connection.msgtype == IMAGE else message.format
            count = sum(c.msgcount for c in connections)
            found.append(Stream(topic, connection.msgtype, count, encoding))
            break
    return found


def _choose(
    path: Path,
    streams: list[Stream],
    wanted: str | None,
    kind: str,
    fits: Callable[[Stream], bool],
    preferred: tuple[str, ...],
) -> Stream:
    """The stream ``wanted`` names, else the one of this kind whose name is most preferred."""
    if wanted is not None:
        named = [s for s in streams if s.topic == wanted]
        if not named:
            listed = ", ".join(s.topic for s in streams) or "none"
            raise UserError(f"{path}: no image topic {wanted!r} (image topics: {listed})")
        return named[0]
    candidates = [s for s in streams if fits(s)]
    if not candidates:
        listed = ", ".join(f"{s.topic} ({s.encoding})" for s in streams) or "none"
        raise UserError(f"{path}: no {kind} image topic (image topics: {listed}); pass --{kind[:5]}-topic")
    for word in preferred:
        named = [s for s in candidates if word in s.topic.lower()]
        if len(named) == 1:
            return named[0]
        if named:
            candidates = named
            break
    if len(candidates) > 1:
        listed = ", ".join(s.topic for s in candidates)
        flag = "--color-topic" if kind == "colour" else "--depth-topic"
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
        return reader.deserialize(raw, connection.msgtype)
    raise UserError(f"{path}: {best.topic} holds no CameraInfo message")


def _intrinsics(info: Any) -> Intrinsics:
    k = np.asarray(info.k if hasattr(info, "k") else info.K, dtype=np.float64).reshape(3, 3)  # ROS 2 | ROS 1
    return Intrinsics(float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]), int(info.width), int(info.height))


def _same_camera(a: Intrinsics, b: Intrinsics) -> bool:
    return (a.width, a.height) == (b.width, b.height) and np.allclose(
        [a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], rtol=1e-4
    )


def _stamp(message: Any, bag_ns: int) -> float:
    """Seconds: the header's stamp, or the bag's receive time where the header has none."""
    header = getattr(message, "header", None)
    if header is not None and (header.stamp.sec or header.stamp.nanosec):
        return header.stamp.sec + header.stamp.nanosec * 1e-9
    return bag_ns * 1e-9


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
        j = int(np.searchsorted(ordered, t))
        near = [ordered[k] for k in (j - 1, j) if 0 <= k < len(ordered)]
        best = min(near, key=lambda d: abs(d - t), default=None)
        if best is not None and abs(best - t) <= max_gap_s:
            matches[i] = (t, float(best))
        else:
            gap = "no depth frames" if best is None else f"nearest depth {abs(best - t) * 1000:.0f} ms away"
            skipped.append((f"{t:.6f}", gap))
    return matches, skipped


def _depth_units_m(reader: Any, depth: Stream) -> float:
    """Metres per raw unit: a RealSense "Depth Units" option in the depth sensor's namespace, else REP 118."""
    if "32FC1" in depth.encoding:
        return 1.0
    sensor = depth.topic.split("/")[:3]  # /device_0/sensor_N
    option = "/".join([*sensor, "option", "Depth Units", "value"])
    for _, _, message in _messages(reader, option):
        return float(message.data)
    return 0.001


def _colour_image(message: Any, msgtype: str) -> tuple[bytes, str] | np.ndarray:
    """A compressed frame's bytes and file suffix as stored, or a raw frame as HxWx3 uint8 RGB."""
    if msgtype == COMPRESSED:
        data = bytes(message.data)
        return data, ".png" if data[:8] == b"\x89PNG\r\n\x1a\n" else ".jpg"
    channels, bgr = COLOUR_ENCODINGS[message.encoding]
    rows = np.frombuffer(bytes(message.data), np.uint8).reshape(message.height, message.step)
    pixels = rows[:, : message.width * channels].reshape(message.height, message.width, channels)
    if channels == 1:
        return np.repeat(pixels, 3, axis=2)
    rgb = pixels[..., :3]
    return np.ascontiguousarray(rgb[..., ::-1] if bgr else rgb)


def _depth_image(message: Any, msgtype: str, units_m: float) -> np.ndarray:
    """A depth frame in metres, float32 (0 where there is no reading)."""
    if msgtype == COMPRESSED:  # image_transport's compressedDepth: a 12-byte header, then a 16-bit PNG
        data = bytes(message.data)
        start = data.find(b"\x89PNG\r\n\x1a\n")
        if start < 0:
            raise UserError(f"compressed depth format {message.format!r} is not PNG; record raw or compressedDepth png")
        with Image.open(io.BytesIO(data[start:])) as im:
            return np.asarray(im, dtype=np.float32) * units_m
    dtype = np.dtype(DEPTH_ENCODINGS[message.encoding]).newbyteorder(">" if message.is_bigendian else "<")
    rows = np.frombuffer(bytes(message.data), np.uint8).reshape(message.height, message.step)
    values = rows[:, : message.width * dtype.itemsize].copy().view(dtype).reshape(message.height, message.width)
    depth = values.astype(np.float32) * units_m
    depth[~np.isfinite(depth)] = 0
    return depth


def _write_pairs(
    reader: Any, out: Path, colour: Stream, depth: Stream, matches: dict[int, tuple[float, float]], geometry: Geometry
) -> list[tuple[str, Path, Path]]:
    """Write each matched pair's colour (as stored, or PNG) and depth (16-bit mm in the colour camera)."""
    (out / "color").mkdir(parents=True, exist_ok=True)
    (out / "depth").mkdir(parents=True, exist_ok=True)
    wanted_colour = {i: f"{c:.6f}" for i, (c, _) in matches.items()}
    wanted_depth: dict[float, list[str]] = {}
    for i, (_, d) in matches.items():
        wanted_depth.setdefault(d, []).append(wanted_colour[i])
    colour_files: dict[str, Path] = {}
    index = -1
    for connection, _, message in _messages(reader, colour.topic):
        index += 1
        name = wanted_colour.get(index)
        if name is None:
            continue
        image = _colour_image(message, connection.msgtype)
        if isinstance(image, tuple):
            data, suffix = image
            colour_files[name] = out / "color" / f"{name}{suffix}"
            colour_files[name].write_bytes(data)
        else:
            colour_files[name] = out / "color" / f"{name}.png"
            Image.fromarray(image).save(colour_files[name])
    for connection, bag_ns, message in _messages(reader, depth.topic):
        names = wanted_depth.get(_stamp(message, bag_ns))
        if not names:
            continue
        metres = _depth_image(message, connection.msgtype, geometry.units_m)
        if geometry.moves:
            g = geometry
            metres = reproject_depth(metres, g.depth_camera, g.colour_camera, g.rotation, g.translation)
        millimetres = np.clip(np.rint(metres * DEPTH_SCALE), 0, 65535).astype(np.uint16)
        for name in names:
            Image.fromarray(millimetres).save(out / "depth" / f"{name}.png")
    return [(name, colour_files[name], out / "depth" / f"{name}.png") for name in wanted_colour.values()]
