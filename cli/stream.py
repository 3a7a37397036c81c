"""``rgb2cloud stream SOURCE``: a camera, a video, a folder of photos or a recording through ``/v1/stream``.

The client side of the stream for robots: frames go out through one WebSocket (``clients.stream``), and
each answer's depth and point cloud go to every sink asked for (``clients.sinks``): a folder of 16-bit depth
PNGs and PLYs, a ROS 2 bag, live ROS 2 topics over DDS, a live Foxglove server. Answers come as raw float32
metres and raw points, the stream's cheapest encodings. It lives in the command line because it joins the two
torch-free halves the serving install may hold: the clients and the recordings' readers.
"""

from __future__ import annotations

import itertools
import queue
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from contract.encodings import STREAM_MAX_PIXELS
from contract.errors import UserError

CAMERA_HELP = (
    "{}, pixels: a recording's in its own pixels, as fit takes it (its camera is overridden, then scaled to "
    "each photo sent); a camera's, video's or photos' in their frames' pixels"
)


@dataclass(frozen=True)
class Sending:
    """A frame as it goes out: the photo at the size sent, and its camera as the stream's options in that
    photo's pixels (None: the service's own camera, from the photo's EXIF or the model's)."""

    frame: Any  # recordings.sources.SourceFrame
    camera: dict[str, float] | None


@dataclass(frozen=True)
class Unreadable:
    """A photo the client cannot open to fit it to the stream: its frame's name, and why in a few words."""

    name: str
    why: str


def unreadable_reason(error: Exception) -> str:
    """Why Pillow could not open a photo, as the one line that names it says it."""
    from PIL import Image, UnidentifiedImageError

    if isinstance(error, UnidentifiedImageError):
        return "not an image Pillow can read"
    if isinstance(error, Image.DecompressionBombError):
        return f"over Pillow's decompression-bomb limit of {2 * Image.MAX_IMAGE_PIXELS:,} pixels"
    return f"cannot be read ({error})"


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

    def __call__(self, frame: Any) -> Sending | Unreadable:
        """The frame as it goes out, or why it cannot: a photo that is no image, is cut off where it must be
        decoded here (to be resized), or is over Pillow's decompression-bomb limit."""
        from PIL import Image

        try:
            return self._fitted(frame)
        except (OSError, ValueError, Image.DecompressionBombError) as e:  # OSError: unidentified or truncated
            return Unreadable(frame.name, unreadable_reason(e))

    def _fitted(self, frame: Any) -> Sending:
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


def paced(frames: Iterable[Any], rate: float) -> Iterator[Any]:
    """Frames no sooner than their stamps say, at ``rate`` times their recorded pace (as ``ros2 bag play``
    plays); ``rate`` 0 lets them go as fast as they are taken."""
    began: tuple[float, int] | None = None
    for frame in frames:
        if rate > 0:
            if began is None:
                began = (time.monotonic(), frame.stamp_ns)
            wait = began[0] + (frame.stamp_ns - began[1]) / 1e9 / rate - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        yield frame


def run_stream(
    source: Any,
    url: str,
    sinks: list[Any],
    given: dict[str, Any],
    given_camera: dict[str, float],
    max_pixels: int,
    tally: Tally,
    rate: float = 0.0,
    skip_written: Any = None,
) -> None:
    """Every frame through one stream into every sink (``clients.sinks``); ``tally`` counts what became of the
    frames, also when the stream ends in an error. ``given_camera`` is the user's camera for a source whose
    frames carry none, in its frames' pixels; ``rate`` paces a recording (``paced``); ``skip_written`` leaves
    out frames a folder holds already. A photo the client cannot open is one line that names it, and the
    stream goes on with the next."""
    from tqdm import tqdm
    from websockets.exceptions import InvalidHandshake

    from clients.stream import answers, open_stream

    frames = source.frames
    if skip_written is not None and not source.live:
        frames = (f for f in frames if not all(p.exists() for p in skip_written.paths(f.name)))
    frames = paced(frames, 0.0 if source.live else rate)

    def say(line: str) -> None:
        tqdm.write(line, file=sys.stderr)

    fitting = Fitting(max_pixels, given_camera, say)

    def readable(frames: Iterable[Any]) -> Iterator[Sending]:
        for frame in frames:
            fitted = fitting(frame)
            if isinstance(fitted, Unreadable):
                tally.unreadable += 1
                say(f"{fitted.name}: skipped, {fitted.why}")
            else:
                yield fitted

    sending = readable(frames)
    first = next(sending, None)
    if first is None:
        return
    sending = itertools.chain([first], sending)
    bar = tqdm(desc="stream", unit="frame", mininterval=1.0)
    started = time.perf_counter()
    try:
        socket = open_stream(url, max_pixels=max_pixels, **stream_options(first, given))
    except InvalidHandshake as e:
        raise UserError(f"{url}: the service refused the stream: {e}") from None
    writer = Writer(sinks)
    try:
        with socket:
            for answer in answers(socket, sending, lambda s: s.frame.data, source.live, options_of=lambda s: s.camera):
                bar.update(1)
                tally.sent_again += answer.tries > 1
                if answer.error is not None:
                    tally.refused += 1
                    say(f"{answer.item.frame.name}: {answer.error}")
                    continue
                writer.put(answer)
                rate = writer.written / max(1e-9, time.perf_counter() - started)
                bar.set_postfix(fps=f"{rate:.1f}", skipped=answer.header["skipped"], refresh=False)
    finally:  # the bar closed and every answer counted whatever ends the stream
        failure = writer.finish()
        bar.close()
        tally.written = writer.written
        if failure is not None:
            if sys.exc_info()[1] is None:
                raise failure
            say(f"also, an output failed: {failure}")  # the error on its way up is the one the user sees


@dataclass
class Tally:
    """What became of a stream's frames: written to every sink, refused by the service (its words said per
    frame), skipped as photos the client could not open (each named as it was), and sent again after a 503
    (the service was busy), whether or not they then came back."""

    written: int = 0
    refused: int = 0
    unreadable: int = 0
    sent_again: int = 0

    @property
    def skipped(self) -> int:
        return self.refused + self.unreadable

    def summary(self) -> str:
        said = [f"{self.written} frames written"]
        if self.refused:
            said.append(f"{self.refused} refused by the service")
        if self.unreadable:
            said.append(f"{self.unreadable} skipped as unreadable")
        if self.sent_again:
            said.append(f"{self.sent_again} sent again while the service was busy")
        return ", ".join(said)


class Writer:
    """Writes answers to the sinks in a thread of its own, in order, so the next answers are read (and the
    service kept busy) while a frame's files and messages go out. ``finish`` writes what is queued and stops;
    after Ctrl-C too, so each frame is written whole or not at all."""

    def __init__(self, sinks: list[Any], depth: int = 8):
        self.sinks, self.written = sinks, 0
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (answer := self._queue.get()) is not None:
            if self._failure is None:
                try:
                    from clients.sinks import decoded

                    frame = decoded(answer.item.frame, answer.header, answer.payloads)
                    for sink in self.sinks:
                        sink.write(frame)
                    self.written += 1
                except BaseException as e:  # a full disk: raised where answers are read
                    self._failure = e

    def put(self, answer: Any) -> None:
        if self._failure is not None:
            raise self._failure
        self._queue.put(answer)

    def finish(self) -> BaseException | None:
        """Writes what is queued and stops; the failure that stopped the writing, if any, for the caller to
        raise or, where an error is already on its way up, to report beside it."""
        self._queue.put(None)
        self._thread.join()
        return self._failure


#: Why a source's own depth cannot go beside the model's.
NOT_REGISTERED = "bags, Kinect and phone recordings have it; this source's depth is as its sensor took it"

# The longer options' types, named here so that ``stream`` reads as the list of its options.
Source = Annotated[
    str, typer.Argument(help="a camera (/dev/videoN or an index), a video, a folder of photos, or a recording")
]
Foxglove = Annotated[
    str | None,
    typer.Option(help="serve the bag's topics live to Foxglove at [HOST:]PORT (8765; 0.0.0.0:8765 for all)"),
]
Rate = Annotated[
    float | None,
    typer.Option(
        min=0,
        help="a recording's or video's pace: 1 as recorded (the default with --ros2 or --foxglove), "
        "0 as fast as the service answers (the default otherwise)",
    ),
]
WithSensorDepth = Annotated[
    bool, typer.Option(help="bag, ROS 2, Foxglove: a recording's own depth, registered to colour, beside the model's")
]
Namespace = Annotated[
    str,
    typer.Option(help="bag, ROS 2, Foxglove: the topics' namespace (realsense-ros's names under it; not the sensor's)"),
]
Ros2 = Annotated[bool, typer.Option("--ros2", help="publish the bag's topics live on ROS 2 (DDS; docs/robotics.md)")]
RosDomain = Annotated[
    int | None, typer.Option(min=0, max=232, help="--ros2: the ROS 2 domain (default: ROS_DOMAIN_ID, else 0)")
]
TfParent = Annotated[
    str | None,
    typer.Option(help="bag, ROS 2, Foxglove: /tf_static places the optical frame under this frame (camera_link)"),
]


def open_live_sinks(
    sinks: list[Any], bag: Path | None, ros2_domain: int | None, foxglove: str | None, messages: Any
) -> None:
    """The bag, the ROS 2 publishers and the Foxglove server, each appended to ``sinks`` as it opens, so the
    caller closes those that did open when a later one fails."""
    from clients.sinks.bag import BagSink
    from clients.sinks.foxglove import FoxgloveSink
    from clients.sinks.ros2 import Ros2Sink

    if bag is not None:
        sinks.append(BagSink(bag, messages))
    if ros2_domain is not None:
        sinks.append(Ros2Sink(ros2_domain, messages))
        typer.echo(f"ROS 2: publishing under {messages.topics.namespace} in domain {ros2_domain}", err=True)
    if foxglove is not None:
        sinks.append(live := FoxgloveSink(foxglove, messages))
        typer.echo(f"Foxglove: open ws://{live.host}:{live.port} (docs/robotics.md)", err=True)


def stream(
    source: Source,
    out: Annotated[Path | None, typer.Option("-o", "--out", help="write NAME.depth.png (16-bit mm) here")] = None,
    bag: Annotated[Path | None, typer.Option(help="write a ROS 2 bag (MCAP) into this new folder")] = None,
    ros2: Ros2 = False,
    ros_domain: RosDomain = None,
    foxglove: Foxglove = None,
    rate: Rate = None,
    pointcloud: Annotated[bool, typer.Option(help="with --out: also NAME.ply")] = False,
    with_colour: Annotated[bool, typer.Option(help="bag, Foxglove: the photos too")] = False,
    with_sensor_depth: WithSensorDepth = False,
    namespace: Namespace = "/rgb2cloud",
    tf_parent: TfParent = None,
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
    """Stream frames through a running service; depth and clouds to a folder, a bag, ROS 2 or Foxglove live."""
    from websockets.exceptions import ConnectionClosed

    from cli.service import service_url
    from clients.sinks.folder import FolderSink
    from clients.sinks.ros_messages import RosMessages, Topics
    from clients.stream import StreamRefused
    from recordings.folders import CameraFile
    from recordings.formats import ReadOptions
    from recordings.sources import stream_source

    ros2_domain = chosen_outputs(out, bag, ros2, ros_domain, foxglove)
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
            raise UserError(f"{source}: --with-sensor-depth needs depth registered to colour ({NOT_REGISTERED})")
        messages = RosMessages(Topics(namespace), found.frame_id, with_colour, with_sensor_depth, tf_parent)
        folder = FolderSink(out, pointcloud) if out is not None else None
        sinks: list[Any] = [] if folder is None else [folder]
        tally: Tally | None = None
        try:
            open_live_sinks(sinks, bag, ros2_domain, foxglove, messages)
            skip_written = folder if folder is not None and len(sinks) == 1 and not overwrite else None
            live = ros2 or foxglove is not None
            pace = rate if rate is not None else (1.0 if live else 0.0)
            target = url or service_url()
            typer.echo(f"streaming {source} ({found.description}) to {target}", err=True)
            tally = Tally()
            run_stream(found, target, sinks, given, given_camera, max_pixels, tally, pace, skip_written)
        except (StreamRefused, ConnectionClosed) as e:
            raise UserError(f"the stream ended: {e}") from None
        except KeyboardInterrupt:
            typer.echo("stopped (Ctrl-C): what was written is complete", err=True)
            raise typer.Exit(130) from None
        finally:
            try:
                close_all(sinks, lambda line: typer.echo(line, err=True))
            finally:  # what became of the frames, however the stream ended (a sink's shortfall once it closed)
                if tally is not None:
                    shortfall = "".join(sink.shortfall() for sink in sinks if hasattr(sink, "shortfall"))
                    typer.echo(tally.summary() + shortfall)
    if tally is not None and tally.skipped:
        raise typer.Exit(1)


def close_all(sinks: list[Any], echo: Callable[[str], None]) -> None:
    """Closes every sink, each whatever the others do: one that fails to close (a full disk under the bag)
    never leaves the next open. The first failure is raised once all are closed, unless an error is already
    on its way up (called from a ``finally``): that one is what the user sees, and the failures to close
    are each echoed as a line of their own."""
    failures = []
    for sink in sinks:
        try:
            sink.close()
        except Exception as e:
            failures.append(e)
    in_flight = sys.exc_info()[1] is not None
    for failure in failures if in_flight else failures[1:]:
        echo(f"also, an output failed to close: {failure}")
    if failures and not in_flight:
        raise failures[0]


def chosen_outputs(
    out: Path | None, bag: Path | None, ros2: bool, ros_domain: int | None, foxglove: str | None
) -> int | None:
    """Checks that some output was asked for, and gives the ROS 2 domain (None without --ros2)."""
    from clients.sinks.ros2 import domain_id

    if out is None and bag is None and not ros2 and foxglove is None:
        raise UserError("nothing to write: give --out DIR, --bag DIR, --ros2 and/or --foxglove [HOST:]PORT")
    if ros_domain is not None and not ros2:
        raise UserError("--ros-domain is for --ros2")
    return domain_id(ros_domain) if ros2 else None
