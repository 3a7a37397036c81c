"""``rgb2cloud stream SOURCE``: a camera, a video, a folder of photos or a recording through ``/v1/stream``.

The client side of the stream for robots: frames go out through one WebSocket (``app.stream_client``),
and each answer's depth and point cloud are written to a folder (16-bit depth PNGs, PLYs) and/or a
ROS 2 bag (``recordings.ros2_bag``). Answers come as raw float32 metres and raw points, the stream's
cheapest encodings, and are written with the service's own encoders, so a PNG here is byte for byte
what ``/depth`` returns. It lives in the command line because it joins the two torch-free halves the
serving install may hold: the service's client and the recordings' readers.
"""

from __future__ import annotations

import itertools
import queue
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from contract.errors import UserError

CAMERA_HELP = (
    "{}, pixels: a recording's in its own pixels, as fit takes it (its camera is overridden, then scaled to "
    "each photo sent); a camera's, video's or photos' in their frames' pixels"
)


@dataclass
class Outputs:
    """Where answers go: a folder (``out``, with PLYs if ``pointcloud``) and/or an open bag."""

    out: Path | None
    pointcloud: bool
    bag: Any | None  # recordings.ros2_bag.DepthBag
    with_colour: bool
    with_sensor_depth: bool

    def paths(self, name: str) -> list[Path]:
        if self.out is None:
            return []
        return [self.out / f"{name}.depth.png", *([self.out / f"{name}.ply"] if self.pointcloud else [])]

    def write(self, frame: Any, header: dict[str, Any], payloads: dict[str, bytes]) -> None:
        from app.imaging import encode_depth_png
        from app.ply import encode_ply
        from app.stream_client import raw_depth, raw_points
        from contract.geometry import POINT, Intrinsics

        entries = {entry["kind"]: entry for entry in header["payloads"]}
        metres = raw_depth(entries["depth"], payloads["depth"])
        xyz, rgb = raw_points(entries["pointcloud"], payloads["pointcloud"])
        if self.out is not None:
            depth_path, *ply_path = self.paths(frame.name)
            depth_path.write_bytes(encode_depth_png(metres))
            if ply_path:
                points = np.empty(len(xyz), dtype=POINT)
                for i, axis in enumerate("xyz"):
                    points[axis] = xyz[:, i]
                for i, channel in enumerate(("red", "green", "blue")):
                    points[channel] = rgb[:, i]
                ply_path[0].write_bytes(encode_ply(points))
        if self.bag is not None:
            k = Intrinsics(**header["intrinsics"])
            stamp, bag, topics = frame.stamp_ns, self.bag, self.bag.topics
            bag.depth_image(topics["depth"], stamp, metres)
            bag.camera_info(topics["depth_info"], stamp, k)
            bag.point_cloud(stamp, xyz, rgb)
            if self.with_colour:
                bag.colour(stamp, frame.data, k)
            if self.with_sensor_depth and (sensor := frame.sensor_metres()) is not None:
                bag.depth_image(topics["sensor_depth"], stamp, sensor)
                bag.camera_info(topics["sensor_depth_info"], stamp, k.resized(sensor.shape[1], sensor.shape[0]))
            bag.frames += 1


#: The service's default limit on a stream frame's pixels (RGB2CLOUD_STREAM_MAX_PIXELS): larger photos are
#: resized to fit before they are sent, their camera with them.
STREAM_MAX_PIXELS = 3840 * 2160


@dataclass(frozen=True)
class Sending:
    """A frame as it goes out: the photo at the size sent, and its camera as the stream's options in that
    photo's pixels (None: the service's own camera, from the photo's EXIF or the model's)."""

    frame: Any  # recordings.sources.SourceFrame
    camera: dict[str, float] | None


def stream_options(first: Sending, given: dict[str, Any]) -> dict[str, Any]:
    """The stream's query: both outputs, raw float depth and raw points, and the first frame's camera (each
    later frame's is sent as it changes)."""
    options = {"output": "both", "depth_encoding": "raw32", "cloud_encoding": "raw"}
    return options | {k: v for k, v in given.items() if v is not None} | (first.camera or {})


class Fitting:
    """Each frame as it is sent: resized to the stream's pixel limit if it is over (said once), with its
    camera in the pixels of the photo sent. A recording's camera comes in each frame (the user's overrides
    already applied in the recording's pixels by its reader); a camera's, video's or photos' is what the
    user gave in their frames' pixels, only the values given, so the service fills in the rest as ``/depth``
    does."""

    def __init__(self, max_pixels: int, given: dict[str, float], say: Any):
        self.max_pixels, self.given, self.say, self.said = max_pixels, given, say, False

    def __call__(self, frame: Any) -> Sending:
        import dataclasses
        import io

        from PIL import Image

        from contract.geometry import resized_coordinate

        with Image.open(io.BytesIO(frame.data)) as im:
            width, height = im.size
            sx = sy = 1.0
            if width * height > self.max_pixels:
                scale = (self.max_pixels / (width * height)) ** 0.5
                size = max(1, int(width * scale)), max(1, int(height * scale))
                if not self.said:
                    self.say(
                        f"photos of {width}x{height} are over the stream's {self.max_pixels:,} pixels: sent at "
                        f"{size[0]}x{size[1]}, their camera scaled to match"
                    )
                    self.said = True
                out = io.BytesIO()
                # Its EXIF goes with it: the service turns it upright and reads its focal length (which
                # scales with the stored size) as it would the photo's own.
                resized = im.convert("RGB").resize(size, Image.Resampling.LANCZOS)
                resized.save(out, format="JPEG", quality=90, exif=im.getexif())
                frame = dataclasses.replace(frame, data=out.getvalue())
                sx, sy = size[0] / width, size[1] / height
                width, height = size
        if frame.camera is not None:
            k = frame.camera.resized(width, height)
            return Sending(dataclasses.replace(frame, camera=k), {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy})
        given = dict(self.given)
        if ("fx" in given) != ("fy" in given):  # as /depth takes one focal length: both, in the photo's pixels
            given["fx"] = given["fy"] = given.get("fx", given.get("fy"))
        scaled = {
            "fx": lambda v: v * sx,
            "fy": lambda v: v * sy,
            "cx": lambda v: resized_coordinate(v, sx),
            "cy": lambda v: resized_coordinate(v, sy),
        }
        return Sending(frame, {key: scaled[key](v) for key, v in given.items()} or None)


def run_stream(
    source: Any,
    url: str,
    outputs: Outputs,
    given: dict[str, Any],
    given_camera: dict[str, float],
    overwrite: bool,
    max_pixels: int,
) -> tuple[int, int]:
    """Every frame through one stream into ``outputs``; (frames written, frames refused). ``given_camera``
    is the user's camera for a source whose frames carry none, in its frames' pixels."""
    from tqdm import tqdm
    from websockets.exceptions import InvalidHandshake

    from app.stream_client import answers, open_stream

    frames = source.frames
    if not source.live and outputs.out is not None and outputs.bag is None and not overwrite:
        frames = (f for f in frames if not all(p.exists() for p in outputs.paths(f.name)))

    def say(line: str) -> None:
        tqdm.write(line, file=sys.stderr)

    sending = map(Fitting(max_pixels, given_camera, say), frames)
    first = next(sending, None)
    if first is None:
        return 0, 0
    sending = itertools.chain([first], sending)
    refused = 0
    bar = tqdm(desc="stream", unit="frame", mininterval=1.0)
    started = time.perf_counter()
    try:
        socket = open_stream(url, **stream_options(first, given))
    except InvalidHandshake as e:
        raise UserError(f"{url}: the service refused the stream: {e}") from None
    writer = Writer(outputs)
    try:
        with socket:
            for answer in answers(socket, sending, lambda s: s.frame.data, source.live, options_of=lambda s: s.camera):
                bar.update(1)
                if answer.error is not None:
                    refused += 1
                    say(f"{answer.item.frame.name}: {answer.error}")
                    continue
                writer.put(answer)
                rate = writer.written / max(1e-9, time.perf_counter() - started)
                bar.set_postfix(fps=f"{rate:.1f}", skipped=answer.header["skipped"], refresh=False)
    finally:
        writer.finish()
        bar.close()
    return writer.written, refused


class Writer:
    """Writes answers in a thread of its own, in order, so the next answers are read (and the service kept
    busy) while a frame's files and bag messages go to disk. ``finish`` writes what is queued and stops;
    after Ctrl-C too, so each frame is written whole or not at all."""

    def __init__(self, outputs: Outputs, depth: int = 8):
        self.outputs, self.written = outputs, 0
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (answer := self._queue.get()) is not None:
            if self._failure is None:
                try:
                    self.outputs.write(answer.item.frame, answer.header, answer.payloads)
                    self.written += 1
                except BaseException as e:  # a full disk: raised where answers are read
                    self._failure = e

    def put(self, answer: Any) -> None:
        if self._failure is not None:
            raise self._failure
        self._queue.put(answer)

    def finish(self) -> None:
        self._queue.put(None)
        self._thread.join()
        if self._failure is not None:
            raise self._failure


def stream(
    source: Annotated[
        str, typer.Argument(help="a camera (/dev/videoN or an index), a video, a folder of photos, or a recording")
    ],
    out: Annotated[Path | None, typer.Option("-o", "--out", help="write NAME.depth.png (16-bit mm) here")] = None,
    bag: Annotated[Path | None, typer.Option(help="write a ROS 2 bag (MCAP) into this new folder")] = None,
    pointcloud: Annotated[bool, typer.Option(help="with --out: also NAME.ply")] = False,
    with_colour: Annotated[bool, typer.Option(help="bag: the photos too, so the bag plays on its own")] = False,
    with_sensor_depth: Annotated[
        bool, typer.Option(help="bag: a recording's own depth, registered to colour, beside the model's")
    ] = False,
    namespace: Annotated[
        str, typer.Option(help="bag: the topics' namespace (realsense-ros's names under it; not the sensor's own)")
    ] = "/rgb2cloud",
    url: Annotated[str | None, typer.Option(help="service URL (default: RGB2CLOUD_HOST and _PORT)")] = None,
    model: Annotated[str | None, typer.Option(help="NAME or NAME:VERSION (default: the service's)")] = None,
    fx: Annotated[float | None, typer.Option(help=CAMERA_HELP.format("focal length x"))] = None,
    fy: Annotated[float | None, typer.Option(help=CAMERA_HELP.format("focal length y"))] = None,
    cx: Annotated[float | None, typer.Option(help=CAMERA_HELP.format("principal point x"))] = None,
    cy: Annotated[float | None, typer.Option(help=CAMERA_HELP.format("principal point y"))] = None,
    max_pixels: Annotated[
        int, typer.Option(min=1, help="photos over this many pixels are resized to fit (the service's stream limit)")
    ] = STREAM_MAX_PIXELS,
    stride: Annotated[int, typer.Option(min=1, max=64, help="point clouds: every stride-th row and column")] = 1,
    max_depth: Annotated[float, typer.Option(help="point clouds: drop points farther (m)")] = 100.0,
    smooth: Annotated[str, typer.Option(help="off | temporal (docs/api.md#streams)")] = "off",
    format: Annotated[str | None, typer.Option(help="the recording's format, where it cannot be told")] = None,
    color_topic: Annotated[str | None, typer.Option(help="a bag's colour image topic (default: found)")] = None,
    depth_topic: Annotated[str | None, typer.Option(help="a bag's depth image topic (default: found)")] = None,
    max_gap_ms: Annotated[float | None, typer.Option(help="a bag's colour and depth pairing window")] = None,
    overwrite: Annotated[bool, typer.Option(help="--out: redo frames whose files exist")] = False,
) -> None:
    """Stream frames through a running service; write depth and point clouds to a folder or a ROS 2 bag."""
    from websockets.exceptions import ConnectionClosed

    from app.client import service_url
    from app.stream_client import StreamRefused
    from recordings.folders import CameraFile
    from recordings.formats import ReadOptions
    from recordings.ros2_bag import DepthBag, Topics
    from recordings.sources import stream_source

    if out is None and bag is None:
        raise UserError("nothing to write: give --out DIR and/or --bag DIR")
    overrides = CameraFile(fx, fy, cx, cy)
    given = {"model": model, "stride": stride, "max_depth": max_depth, "smooth": smooth}
    with tempfile.TemporaryDirectory(prefix="rgb2cloud-stream-") as scratch:
        gap = None if max_gap_ms is None else max_gap_ms / 1000
        topics = {"color_topic": color_topic, "depth_topic": depth_topic}
        options = ReadOptions(overrides, **topics, max_gap_s=gap, max_frames=None)
        found = stream_source(source, format, options, Path(scratch))
        # A camera's, video's or photos' frames carry no camera: the user's goes with each, in its own pixels.
        camera = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
        given_camera = {} if found.recorded_camera else {k: v for k, v in camera.items() if v is not None}
        if with_sensor_depth and not found.registered:
            raise UserError(
                f"{source}: --with-sensor-depth needs depth registered to colour (bags, Kinect and phone "
                "recordings); this source's depth is as its sensor took it"
            )
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
        writer = DepthBag(bag, Topics(namespace), found.frame_id) if bag is not None else None
        outputs = Outputs(out, pointcloud, writer, with_colour, with_sensor_depth)
        typer.echo(f"streaming {source} ({found.description}) to {url or service_url()}", err=True)
        try:
            written, refused = run_stream(
                found, url or service_url(), outputs, given, given_camera, overwrite, max_pixels
            )
        except (StreamRefused, ConnectionClosed) as e:
            raise UserError(f"the stream ended: {e}") from None
        except KeyboardInterrupt:
            typer.echo("stopped (Ctrl-C): what was written is complete", err=True)
            raise typer.Exit(130) from None
        finally:
            if writer is not None:
                writer.close()
    typer.echo(f"{written} frames written" + (f", {refused} refused" if refused else ""))
    if refused:
        raise typer.Exit(1)
