"""``rgb2cloud stream SOURCE``: a camera, a video, a folder of photos or a recording through ``/v1/stream``.

The client side of the stream for robots: frames go out through one WebSocket (``clients.stream``), and
each answer's depth and point cloud go to every sink asked for (``clients.sinks``): a folder of 16-bit depth
PNGs and PLYs, a ROS 2 bag, live ROS 2 topics over DDS, a live Foxglove server. Answers come as raw float32
metres and raw points, the stream's cheapest encodings. It lives in the command line because it joins the two
torch-free halves the serving install may hold: the clients and the recordings' readers.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from cli.stream_loop import Tally, close_all, run_stream
from contract.encodings import STREAM_MAX_PIXELS
from contract.errors import UserError

if TYPE_CHECKING:
    from clients.sinks import Sink
    from clients.sinks.ros_messages import RosMessages

CAMERA_HELP = (
    "{}, pixels: a recording's in its own pixels, as fit takes it (its camera is overridden, then scaled to "
    "each photo sent); a camera's, video's or photos' in their frames' pixels"
)


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
    sinks: list[Sink], bag: Path | None, ros2_domain: int | None, foxglove: str | None, messages: RosMessages
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
        sinks: list[Sink] = [] if folder is None else [folder]
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
            close_and_tell(sinks, tally)
    if tally is not None and tally.skipped:
        raise typer.Exit(1)


def close_and_tell(sinks: list[Sink], tally: Tally | None) -> None:
    """Every sink closed (``close_all``), then the last line, however the stream ended: what became of the frames
    (where it began), with each sink's shortfall, known once it has closed."""
    try:
        close_all(sinks, lambda line: typer.echo(line, err=True))
    finally:
        if tally is not None:
            typer.echo(tally.summary() + "".join(sink.shortfall() for sink in sinks if hasattr(sink, "shortfall")))


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
