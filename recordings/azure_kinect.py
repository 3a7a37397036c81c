"""Azure Kinect and Orbbec Femto recordings: the Matroska file ``k4arecorder`` writes, as colour/depth pairs.

The layout (Microsoft's Azure Kinect "record file format"; Orbbec's K4A wrapper writes the same):

- track ``COLOR``: MJPEG, or raw NV12, YUY2 or BGRA, its mode in the ``K4A_COLOR_MODE`` tag (``MJPG_720P``);
- track ``DEPTH``: 16-bit millimetres (``b16g``), its mode in ``K4A_DEPTH_MODE`` (``NFOV_UNBINNED``);
- ``IR`` and ``IMU`` tracks, which fit does not use;
- the attachment ``calibration.json``: the device's factory calibration, each camera's intrinsics
  normalised to its full sensor (1024x1024 depth, 4096x3072 colour) with a Brown-Conrady lens, and
  each camera's pose relative to the depth camera;
- the container tag ``K4A_DEPTH_DELAY_NS``: how much later than colour the depth was taken.

This reader turns each camera's calibration into the recording mode's, as the Sensor SDK does
(``SensorMode``: the sensor binned, then cropped, with OpenCV's pixel-centre convention); pairs each
colour frame with the depth frame nearest its time plus the delay; undoes both lenses with OpenCV
(``recordings.lens``); moves depth into the colour camera with the calibration's rigid transform
(``reproject_depth``, as for bags); and writes each kept pair at the size fit trains at.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from contract.errors import UserError
from contract.geometry import Intrinsics
from recordings.folders import CameraFile
from recordings.frames import DEFAULT_MAX_FRAMES, PairsReader, kept_note, nearest_stamp, spread
from recordings.kinect_calibration import (
    COLOUR_RESOLUTIONS,
    DEPTH_MODES,
    SensorMode,
    attached_calibration,
    depth_to_colour,
    mode_lens,
)
from recordings.lens import Lens
from recordings.pair_writer import PairWriter, damaged_note, written_pairs
from recordings.registration import reproject_depth

#: Colour and depth further apart than this (after the recorded depth delay) are not a pair.
DEFAULT_MAX_GAP_S = 0.02
#: The colour formats k4arecorder and the SDK record (``K4A_COLOR_MODE`` is FORMAT_RESOLUTION).
COLOUR_FORMATS = ("MJPG", "NV12", "YUY2", "BGRA", "BGRA32")


@dataclass(frozen=True)
class KinectOptions:
    """Which frames to keep, how far apart a pair may be, and the colour camera's intrinsics from the command line
    (in the pixels of the recorded photos, applied before anything is written)."""

    max_gap_s: float = DEFAULT_MAX_GAP_S
    every: int = 1
    max_frames: int | None = DEFAULT_MAX_FRAMES
    camera: CameraFile = field(default_factory=CameraFile)


def is_kinect_recording(root: Path) -> bool:
    """A Matroska file: what ``k4arecorder`` and Orbbec's recorder write."""
    return Path(root).is_file() and Path(root).suffix.lower() == ".mkv"


def read_kinect(path: Path, out_dir: Path, options: KinectOptions | None = None) -> PairsReader:
    """The recording's colour frames with their depth in the colour camera, written under ``out_dir``.

    A file damaged anywhere (cut short, a broken header) is one line that names it, never a traceback.
    """
    import av

    path, options = Path(path), options or KinectOptions()
    try:
        with av.open(str(path)) as container:
            recording = _recording(container, path, options)
            stamps = _stamps(container, recording)
        pairs = _pairs(path, recording, stamps, options)
        with av.open(str(path)) as container:
            written, damaged = _write(container, Path(out_dir), recording, pairs)
    except UserError:
        raise
    except (av.error.FFmpegError, EOFError) as e:  # PyAV's own errors: a failed write of ours is not the file's
        why = getattr(e, "strerror", None) or "cut short"
        raise UserError(f"{path}: not a readable Matroska recording ({why})") from None
    return written_pairs(
        path.name, written, recording.written_camera, pairs.skipped + damaged, _notes(recording, pairs, damaged)
    )


@dataclass(frozen=True)
class KinectLayout:
    """The layout of one Kinect file: its tracks and modes, both cameras in the recording's modes, the transform."""

    colour_track: int  # stream indices: each pass opens the file afresh
    depth_track: int
    colour_size: tuple[int, int]
    colour_mode: str
    depth_mode: str
    others: list[str]
    colour_lens: Lens
    depth_lens: Lens
    rotation: np.ndarray
    translation: np.ndarray
    delay_s: float
    notes: list[str]
    writer_size: tuple[int, int]

    @property
    def written_camera(self) -> Intrinsics:
        """The undistorted colour camera at the size the pairs are written at."""
        return self.colour_lens.camera.resized(*self.writer_size)


def _recording(container: Any, path: Path, options: KinectOptions) -> KinectLayout:
    colour, depth, others = _tracks(container, path)
    depth_mode = depth.metadata.get("K4A_DEPTH_MODE", "")
    colour_mode, colour_sensor = _colour_mode(path, colour)
    if (depth.width, depth.height) != DEPTH_MODES[depth_mode].size:
        raise UserError(
            f"{path}: DEPTH track is {depth.width}x{depth.height}, not {depth_mode}'s {DEPTH_MODES[depth_mode].size}"
        )
    calibration = attached_calibration(container, path)
    depth_lens = mode_lens(path, calibration, "depth", DEPTH_MODES[depth_mode])
    colour_lens = mode_lens(path, calibration, "colour", colour_sensor)
    notes = []
    if options.camera.sets_intrinsics:
        k = colour_lens.camera
        camera = CameraFile.of(k).merged(options.camera).intrinsics(k.width, k.height, path)
        colour_lens = replace(colour_lens, camera=camera)
        k = colour_lens.camera
        notes.append(f"colour camera with the command line's: fx {k.fx:g}, fy {k.fy:g}, cx {k.cx:g}, cy {k.cy:g}")
    rotation, translation = depth_to_colour(path, calibration)
    try:
        delay_s = int(container.metadata.get("K4A_DEPTH_DELAY_NS", "0")) / 1e9
    except ValueError:
        raise UserError(
            f"{path}: K4A_DEPTH_DELAY_NS {container.metadata['K4A_DEPTH_DELAY_NS']!r} is not a number"
        ) from None
    size = PairWriter.written_size(colour.width, colour.height)
    return KinectLayout(
        colour.index,
        depth.index,
        (colour.width, colour.height),
        colour_mode,
        depth_mode,
        others,
        colour_lens,
        depth_lens,
        rotation,
        translation,
        delay_s,
        notes,
        size,
    )


def _tracks(container: Any, path: Path) -> tuple[Any, Any, list[str]]:
    """The COLOR and DEPTH tracks, and the titles of the tracks fit does not use; a missing one is refused."""
    by_title = {
        (s.metadata.get("title") or "").upper(): s for s in container.streams if s.type in ("video", "subtitle")
    }
    if "DEPTH" not in by_title:
        ir = by_title.get("IR")
        why = f"IR only, K4A_IR_MODE {ir.metadata.get('K4A_IR_MODE', '?')}" if ir is not None else "no depth track"
        raise UserError(f"{path}: no DEPTH track ({why}); fit needs depth: record with k4arecorder -d NFOV_UNBINNED")
    mode = by_title["DEPTH"].metadata.get("K4A_DEPTH_MODE", "")
    if mode == "PASSIVE_IR":
        raise UserError(f"{path}: depth mode PASSIVE_IR records infrared only, no depth; record with -d NFOV_UNBINNED")
    if mode not in DEPTH_MODES:
        found = repr(mode) if mode else "none (no K4A_DEPTH_MODE tag)"
        raise UserError(f"{path}: DEPTH track mode {found}: expected one of {', '.join(DEPTH_MODES)}")
    if "COLOR" not in by_title:
        raise UserError(f"{path}: no COLOR track; fit needs photos: record with k4arecorder -c 720p (or another mode)")
    others = sorted(title or "untitled" for title in by_title if title not in ("COLOR", "DEPTH"))
    return by_title["COLOR"], by_title["DEPTH"], others


def _colour_mode(path: Path, colour: Any) -> tuple[str, SensorMode]:
    """The colour track's mode (``MJPG_720P``) and the sensor window it records, checked against its frames."""
    tag = colour.metadata.get("K4A_COLOR_MODE", "")
    fmt, _, resolution = tag.partition("_")
    if fmt not in COLOUR_FORMATS or resolution not in COLOUR_RESOLUTIONS:
        raise UserError(
            f"{path}: COLOR track mode {tag or 'none (no K4A_COLOR_MODE tag)'!r}: expected FORMAT_RESOLUTION with a "
            f"format of {', '.join(COLOUR_FORMATS)} and a resolution of {', '.join(COLOUR_RESOLUTIONS)}"
        )
    sensor = COLOUR_RESOLUTIONS[resolution]
    if (colour.width, colour.height) != sensor.size:
        raise UserError(
            f"{path}: COLOR track is {colour.width}x{colour.height}, not {tag}'s {sensor.size[0]}x{sensor.size[1]}"
        )
    return tag, sensor


def _stamps(container: Any, recording: KinectLayout) -> dict[str, list[float]]:
    """Each track's frame times in seconds, in file order (a first pass that reads packets, decoding none)."""
    stamps: dict[str, list[float]] = {"colour": [], "depth": []}
    kinds = {recording.colour_track: "colour", recording.depth_track: "depth"}
    streams = container.streams
    for packet in container.demux(streams[recording.colour_track], streams[recording.depth_track]):
        if packet.pts is not None and packet.size:
            stamps[kinds[packet.stream.index]].append(float(packet.pts * packet.time_base))
    return stamps


@dataclass(frozen=True)
class Pairs:
    """Kept colour frame index -> depth frame index, with the gap of each, and what was left out."""

    total: int
    kept: int
    kept_note: str
    max_gap_s: float
    depth_count: int
    matches: dict[int, int]
    names: dict[int, str]
    gaps_ms: list[float]
    skipped: list[tuple[str, str]]


def _pairs(path: Path, recording: KinectLayout, stamps: dict[str, list[float]], options: KinectOptions) -> Pairs:
    colour, depth = stamps["colour"], np.asarray(stamps["depth"])
    order = np.argsort(depth, kind="stable")  # file order to time order
    ordered = depth[order]
    kept = spread(list(range(len(colour)))[:: max(1, options.every)], options.max_frames)
    matches, names, gaps, skipped = {}, {}, [], []
    for i in kept:
        name = f"{colour[i]:.6f}"
        found = nearest_stamp(ordered, colour[i] + recording.delay_s)
        if found is None:
            skipped.append((name, "no depth frames"))
            continue
        j, gap = int(order[found[0]]), found[1]
        if gap <= options.max_gap_s:
            matches[i], names[i] = j, name
            gaps.append(gap * 1000)
        else:
            skipped.append(
                (name, f"nearest depth {gap * 1000:.0f} ms from the colour frame's time plus the depth delay")
            )
    if not matches:
        raise UserError(
            f"{path}: no colour frame has depth within {options.max_gap_s * 1000:.0f} ms ({len(colour)} colour, "
            f"{len(depth)} depth frames, depth delay {recording.delay_s * 1000:g} ms); pass --max-gap-ms to allow more"
        )
    note = kept_note(len(colour), len(kept), options.every, options.max_frames)
    return Pairs(len(colour), len(kept), note, options.max_gap_s, len(depth), matches, names, gaps, skipped)


def _write(
    container: Any, out: Path, recording: KinectLayout, pairs: Pairs
) -> tuple[list[tuple[str, Path, Path]], list[tuple[str, str]]]:
    """Decode the kept frames only (stopping after the last), register each depth, write each pair."""
    import av

    writer = PairWriter(out, *recording.colour_size)
    camera = recording.written_camera
    wanted_depth: dict[int, list[int]] = {}
    for i, j in pairs.matches.items():
        wanted_depth.setdefault(j, []).append(i)
    photos: dict[int, np.ndarray] = {}
    depths: dict[int, np.ndarray] = {}
    written, damaged = {}, {}
    seen = {"colour": -1, "depth": -1}
    last = {"colour": max(pairs.matches), "depth": max(wanted_depth)}
    kinds = {recording.colour_track: "colour", recording.depth_track: "depth"}
    streams = container.streams
    for packet in container.demux(streams[recording.colour_track], streams[recording.depth_track]):
        if packet.pts is None or not packet.size:
            continue
        kind = kinds[packet.stream.index]
        seen[kind] += 1
        index = seen[kind]
        if (kind == "colour" and index not in pairs.matches) or (kind == "depth" and index not in wanted_depth):
            if all(seen[k] >= last[k] for k in seen):
                break
            continue
        owners = [index] if kind == "colour" else list(wanted_depth[index])
        try:  # only the decoding: what follows is this reader's own arithmetic, and a bug there keeps its traceback
            frame = packet.decode()[0]
            pixels = frame.to_ndarray(format="rgb24") if kind == "colour" else frame.to_ndarray()
        except (av.error.FFmpegError, IndexError, ValueError):
            damaged.update({pairs.names[i]: f"{kind} frame damaged: FFmpeg cannot decode it" for i in owners})
            continue
        if kind == "colour":
            photos[index] = recording.colour_lens.undistorted(pixels, nearest=False)
        else:
            metres = recording.depth_lens.undistorted(pixels.astype(np.float32) / 1000.0, nearest=True)
            r, t = recording.rotation, recording.translation
            depths[index] = reproject_depth(metres, recording.depth_lens.camera, camera, r, t)
        for i in owners:
            j = pairs.matches[i]
            if i in photos and j in depths and pairs.names[i] not in damaged:
                written[i] = writer.write(pairs.names[i], photos.pop(i), depths[j])
                wanted_depth[j].remove(i)
                if not wanted_depth[j]:  # every photo that takes this depth is written: let it go
                    del depths[j]
        if all(seen[k] >= last[k] for k in seen):
            break
    for i, name in pairs.names.items():
        if i not in written and name not in damaged:
            damaged[name] = "the recording ends before this frame"
    return [written[i] for i in sorted(written)], sorted(damaged.items())


def _notes(recording: KinectLayout, pairs: Pairs, damaged: list[tuple[str, str]]) -> list[str]:
    r = recording
    d, c = r.depth_lens.camera, r.colour_lens.camera
    angle = np.degrees(np.arccos(np.clip((np.trace(r.rotation) - 1) / 2, -1, 1)))
    tx, ty, tz = r.translation * 1000
    notes = [
        f"Azure Kinect recording: colour {r.colour_mode} ({pairs.total} frames), depth {r.depth_mode} "
        f"{d.width}x{d.height} ({pairs.depth_count} frames), depth unit 1 mm"
        + (f"; {', '.join(r.others)} tracks not used" if r.others else ""),
    ]
    if pairs.kept < pairs.total:
        notes.append(pairs.kept_note)
    notes += [
        f"paired within {pairs.max_gap_s * 1000:.0f} ms after the depth delay ({r.delay_s * 1000:g} ms): "
        f"{len(pairs.matches)} of {pairs.kept} colour frames, gap median {statistics.median(pairs.gaps_ms):.1f} ms, "
        f"max {max(pairs.gaps_ms):.1f} ms",
        f"registration: the recording's factory calibration, depth to colour translation "
        f"({tx:.1f}, {ty:.1f}, {tz:.1f}) mm, rotation {angle:.2f} deg; both lenses' Brown-Conrady distortion undone "
        f"(colour fx {c.fx:.1f} at "
        f"{c.width}x{c.height}, depth fx {d.fx:.1f}); written at {r.writer_size[0]}x{r.writer_size[1]}",
        *r.notes,
    ]
    if damaged:
        notes.append(damaged_note(damaged))
    return notes
