"""The output rows of ``bench/stream.py``: a recording through ``rgb2cloud stream``'s own loop to nowhere, a
ROS 2 bag, live ROS 2 topics and Foxglove, each against nowhere: frames/s, the publisher's CPU, and latency
from a frame's capture to its publication (``python bench/stream.py --outputs-only``)."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

SEVEN_SCENES = Path(__file__).resolve().parents[2] / "shared/data/7scenes-redkitchen"
TEST_FRAMES = range(850, 1000)


#: The live outputs' rows, each against streaming to nowhere.
OUTPUTS = ("nowhere", "bag", "ros2", "foxglove")
#: The latency rows: 50 frames spread over the recording (every third of its 30 frames/s) played at a sixth of
#: the recorded pace, 1.7 frames/s, so that every output keeps up and no frame waits behind another.
PACED_FRAMES, PACED_RATE = 50, 1 / 6
#: 7-Scenes' Kinect records 30 frames/s; the recording is stamped at that pace.
RECORDED_FPS = 30


def recording_pairs(frames: int) -> list[tuple[np.ndarray, np.ndarray]]:
    pairs = []
    for n in list(TEST_FRAMES)[:frames]:
        rgb = np.asarray(Image.open(SEVEN_SCENES / f"frame-{n:06d}.color.jpg"))
        mm = np.asarray(Image.open(SEVEN_SCENES / f"frame-{n:06d}.depth.png"))
        pairs.append((rgb, np.where(mm == 65535, 0, mm).astype(np.uint16)))
    return pairs


def sink_rows(url: str, frames: int = len(TEST_FRAMES)) -> str:
    """A 640x480 ROS 2 bag recording (7-Scenes frames 850-999, colour and depth) through ``rgb2cloud stream``'s
    own loop with every topic (colour and sensor depth too), at point strides 1 and 2, to nowhere, a bag, ROS 2
    (the independent C subscriber taking every message) and Foxglove (a client subscribed to every channel):

    - frames/s as fast as the service answers, the outputs taking turns twice each (the best of each kept), and
      what each output costs against nowhere. On one machine that cost holds the subscriber's or viewer's work
      too, as they share its cores with the service;
    - the streaming process's CPU ms a frame in each run, and what the output adds to nowhere's run beside it:
      the publisher's own cost, whoever receives (a Foxglove viewer is a process of its own, outside it);
    - p50 and p95 from a frame's capture to its publication (``Streamed``), the recording paced as
      ``PACED_RATE`` says (as a camera of that rate would give it).

    The table, with its header."""
    from harness.recordings import write_aligned_bag
    from harness.ros2_subscriber import LOOPBACK_16MB, build_subscriber

    allowed = int(Path("/proc/sys/net/core/rmem_max").read_text())
    if allowed < 16 << 20:
        raise SystemExit(f"net.core.rmem_max is {allowed}: sysctl -w net.core.rmem_max=33554432 (docs/robotics.md)")
    os.environ["CYCLONEDDS_URI"] = LOOPBACK_16MB  # this process publishes; the subscriber gets the same
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        recording = write_aligned_bag(Path(tmp) / "recording", "mcap", recording_pairs(frames))
        subscriber = build_subscriber(Path(tmp))
        for stride in (1, 2):
            runs: dict[str, list[Streamed]] = {output: [] for output in OUTPUTS}
            for run in range(2):
                for output in OUTPUTS:
                    scratch = Path(tmp) / f"{stride}-{output}-{run}"
                    runs[output].append(streamed_to(url, recording, scratch, output, stride, subscriber, frames))
            best = {output: max(runs[output], key=lambda r: r.fps) for output in OUTPUTS}
            latencies = {
                output: streamed_to(
                    url,
                    recording,
                    Path(tmp) / f"{stride}-{output}-paced",
                    output,
                    stride,
                    subscriber,
                    frames=PACED_FRAMES,
                    rate=PACED_RATE,
                ).latencies_ms
                for output in OUTPUTS
            }
            for output in OUTPUTS:
                cost = "" if output == "nowhere" else f"{1 - best[output].fps / best['nowhere'].fps:.0%}"
                # Both runs' CPU, and what the output added in each against nowhere's run beside it: their spread.
                cpu = ", ".join(f"{run.cpu_ms:.0f}" for run in runs[output])
                pairs = zip(runs[output], runs["nowhere"], strict=True)
                added = "" if output == "nowhere" else ", ".join(f"{o.cpu_ms - n.cpu_ms:+.0f}" for o, n in pairs)
                p50, p95 = np.percentile(latencies[output], [50, 95])
                rows.append(
                    f"| {LABELS[output]}, point stride {stride} | {best[output].fps:.1f} | {cost} | {cpu} | {added} "
                    f"| {p50:.0f} | {p95:.0f} |"
                )
            per_frame = sum(f.stat().st_size for f in (Path(tmp) / f"{stride}-bag-1" / "bag").iterdir()) / frames
            floor = f"{file_write_ms(per_frame, Path(tmp)):.1f} ms of CPU a frame"
            alone = f"a bag frame at stride {stride} ({per_frame / 1e6:.1f} MB) written to a file alone"
            rows.append(f"| {alone} | | | | {floor} | | |")
    paced = PACED_RATE * RECORDED_FPS * PACED_FRAMES / frames
    header = (
        "| a 640x480 ROS 2 bag recording streamed, every topic | frames/s | cost | client CPU ms a frame, each run "
        f"| the output's share, each run | p50 ms | p95 ms (at {paced:.1f} frames/s) |\n|---|---|---|---|---|---|---|"
    )
    return "\n".join([header, *rows])


LABELS = {
    "nowhere": "to nowhere (answers decoded, nothing written)",
    "bag": "to a ROS 2 bag",
    "ros2": "--ros2, a subscriber taking every message",
    "foxglove": "--foxglove, a client subscribed to every channel",
}


def file_write_ms(size: float, folder: Path, frames: int = 30) -> float:
    """The floor under any bag writer: the CPU time it takes to write ``size`` bytes a frame to a file in
    ``folder`` (where the bags were written)."""
    block = np.random.default_rng(0).bytes(int(size))
    with tempfile.TemporaryFile(dir=folder) as f:
        started = time.process_time()
        for _ in range(frames):
            f.write(block)
        f.flush()
        return (time.process_time() - started) / frames * 1000


class Published:
    """A sink last in the list: when each frame's messages were all out (monotonic seconds, by stamp)."""

    def __init__(self) -> None:
        self.at: list[tuple[int, float]] = []

    def write(self, answer) -> None:
        self.at.append((answer.stamp_ns, time.monotonic()))

    def close(self) -> None:
        pass


#: The Foxglove viewer: subscribes to every channel the server advertises and takes each message (not
#: decoded) until the server ends. A process of its own, so none of its work (websockets reads in a thread
#: of its own) is counted as the stream's.
VIEWER = """
import json, sys
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

with connect(sys.argv[1], subprotocols=["foxglove.sdk.v1"], max_size=None) as socket:
    try:
        for message in socket:
            if isinstance(message, str) and (op := json.loads(message))["op"] == "advertise":
                wanted = [{"id": c["id"], "channelId": c["id"]} for c in op["channels"]]
                socket.send(json.dumps({"op": "subscribe", "subscriptions": wanted}))
    except ConnectionClosed:
        pass
"""


def streamed_to(
    url: str,
    recording: Path,
    scratch: Path,
    output: str,
    stride: int,
    subscriber: Path,
    frames: int,
    rate: float = 0.0,
) -> Streamed:
    """``rgb2cloud stream``'s loop from ``recording`` (``frames`` of it) to one output, and how it went."""
    from cli.stream_frames import paced
    from cli.stream_loop import Tally, close_all, run_stream
    from clients.sinks.bag import BagSink
    from clients.sinks.foxglove import FoxgloveSink
    from clients.sinks.ros2 import Ros2Sink
    from clients.sinks.ros_messages import RosMessages, Topics
    from contract.encodings import STREAM_MAX_PIXELS
    from harness.ros2_subscriber import Subscription, fresh_domain
    from recordings.formats import ReadOptions
    from recordings.sources import stream_source

    source = stream_source(str(recording), None, ReadOptions(max_frames=frames), scratch)
    messages = RosMessages(Topics(), source.frame_id, with_colour=True, with_sensor_depth=True)
    published, sinks, listening, viewer = Published(), [], None, None
    if output == "bag":
        sinks.append(BagSink(scratch / "bag", messages))
    elif output == "ros2":
        domain = fresh_domain()
        wanted = [f"{topic}={msgtype}:{frames}" for topic, msgtype in messages.topic_types()]
        listening = Subscription(subscriber, domain, None, wanted, timeout_s=600, config=os.environ["CYCLONEDDS_URI"])
        sinks.append(Ros2Sink(domain, messages))
    elif output == "foxglove":
        sinks.append(live := FoxgloveSink("127.0.0.1:0", messages))
        viewer = subprocess.Popen([sys.executable, "-c", VIEWER, f"ws://127.0.0.1:{live.port}"])
    sinks.append(published)
    # Paced here rather than in run_stream, to note when each frame is let go: its capture, as a camera's.
    captured: dict[int, float] = {}

    def let_go(frames: Iterator[Any]) -> Iterator[Any]:
        for frame in paced(frames, rate):
            captured[frame.stamp_ns] = time.monotonic()
            yield frame

    started, cpu_started = time.monotonic(), time.process_time()
    try:
        tally = Tally()
        paced_source = replace(source, frames=let_go(source.frames))
        run_stream(paced_source, url, sinks, {"stride": stride}, {}, STREAM_MAX_PIXELS, tally)
        written = tally.written
    finally:
        try:
            close_all(sinks, print)
            seconds, cpu = time.monotonic() - started, time.process_time() - cpu_started
        finally:
            if viewer is not None:  # the server stopped: the viewer ends
                try:
                    viewer.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    viewer.kill()
    if viewer is not None and viewer.returncode:
        raise SystemExit(f"the Foxglove viewer failed (exit {viewer.returncode}): its row would have had no viewer")
    if not written:
        raise SystemExit(f"streaming to {output}: no frame was written")
    if listening is not None:
        listening.wait()  # every message of every frame reached the subscriber
    latencies = [(at - captured[stamp]) * 1000 for stamp, at in published.at]
    return Streamed(written / seconds, latencies, cpu / written * 1000)


@dataclass
class Streamed:
    """One run of ``streamed_to``: frames/s (closing the output included); each frame's ms from its capture
    (the paced recording letting it go, when paced) to its publication (every output's ``write`` returned:
    the bag's messages written, the DDS samples handed to Cyclone DDS, the Foxglove messages queued to the
    server); and the CPU ms a frame that the streaming process spent, all its threads (a viewer is another
    process)."""

    fps: float
    latencies_ms: list[float]
    cpu_ms: float
