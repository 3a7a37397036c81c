"""Stream benchmark: live depth over ``/v1/stream`` against back-to-back POST /depth, in one run.

    python bench/stream.py [--seconds 20] [--soak-frames 5000] [--threads 2]

One service (the bundled default, ONNX Runtime fp32) on 127.0.0.1 answers every row; the client runs
on the same machine. Frames are the 7-Scenes RedKitchen test frames 850-999, 640x480 JPEGs, cycled.
"Camera" rows send at a camera's rate whatever the service does, as a webcam would; "lockstep" sends
the next frame when the last is answered. Latency is from a frame's send to its answer's last byte.
The per-frame work is the service's own decode + inference + encode (the stages each header reports).
The flicker table plays frames 850-999 in order as a stream (``harness.flicker``, docs/quality.md).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import httpx
import numpy as np
from PIL import Image

from app.temporal import TemporalFilter
from clients.stream import open_stream, raw_depth, receive
from contract.geometry import Intrinsics
from harness.flicker import read_pose, sequence_flicker
from harness.service import BUNDLED_REGISTRY, running_service, server_timing
from trainer.machine import cpu_description
from trainer.metrics import MetricAccumulator

SEVEN_SCENES = Path(__file__).resolve().parents[2] / "shared/data/7scenes-redkitchen"
TEST_FRAMES = range(850, 1000)
#: 7-Scenes' depth camera: the sensor's own depth is moved with it.
KINECT_DEPTH = Intrinsics(fx=585.0, fy=585.0, cx=320.0, cy=240.0, width=640, height=480)
T = TypeVar("T")


@dataclass
class Run:
    """What one client saw: each answer's latency (ms) and the service's work for it (ms), over a span."""

    latencies: list[float] = field(default_factory=list)
    work: list[float] = field(default_factory=list)
    inference: list[float] = field(default_factory=list)
    sent: int = 0
    seconds: float = 0.0

    def add(self, latency_s: float, stages_ms: dict[str, float]) -> None:
        self.latencies.append(latency_s * 1000)
        self.work.append(sum(stages_ms.values()))
        self.inference.append(stages_ms["inference"])

    @property
    def fps(self) -> float:
        return len(self.latencies) / self.seconds if self.seconds else 0.0

    def percentile(self, q: float) -> float:
        return float(np.percentile(self.latencies, q))


def jpegs() -> list[bytes]:
    return [(SEVEN_SCENES / f"frame-{n:06d}.color.jpg").read_bytes() for n in TEST_FRAMES]


def posts(url: str, frames: list[bytes], seconds: float) -> Run:
    """Back-to-back POST /depth on one connection, for ``seconds``."""
    run = Run()
    with httpx.Client(timeout=60) as client:
        start = time.perf_counter()
        while time.perf_counter() - start < seconds:
            sent = time.perf_counter()
            response = client.post(f"{url}/depth", files={"image": ("f.jpg", frames[run.sent % len(frames)])})
            response.raise_for_status()
            run.sent += 1
            run.add(time.perf_counter() - sent, server_timing(response))
        run.seconds = time.perf_counter() - start
    return run


def lockstep(url: str, frames: list[bytes], seconds: float, **options) -> Run:
    """One stream that sends the next frame when the last is answered, for ``seconds``."""
    run = Run()
    with open_stream(url, **options) as ws:
        start = time.perf_counter()
        while time.perf_counter() - start < seconds:
            sent = time.perf_counter()
            ws.send(frames[run.sent % len(frames)])
            run.sent += 1
            header, _ = receive(ws)
            run.add(time.perf_counter() - sent, header["stages_ms"])
        run.seconds = time.perf_counter() - start
    return run


def camera(url: str, frames: list[bytes], fps: float, count: int, on_sent=None, **options) -> Run:
    """One stream fed ``count`` frames at ``fps`` whatever the answers do, as a camera feeds it; the last
    frame is always answered (the latest frame wins), so the run ends with its answer."""
    run, sent_at = Run(), {}
    with open_stream(url, **options) as ws:

        def read() -> None:
            while True:
                header, _ = receive(ws)
                if header["type"] == "frame":
                    run.add(time.perf_counter() - sent_at[header["seq"]], header["stages_ms"])
                if header["seq"] == count:
                    return

        reader = threading.Thread(target=read)
        reader.start()
        start = time.perf_counter()
        for seq in range(1, count + 1):
            time.sleep(max(0.0, start + (seq - 1) / fps - time.perf_counter()))
            sent_at[seq] = time.perf_counter()
            ws.send(frames[seq % len(frames)])
            run.sent = seq
            if on_sent is not None:
                on_sent(seq)
        reader.join()
        run.seconds = time.perf_counter() - start
    return run


def cameras(url: str, frames: list[bytes], fps: float, count: int, streams: int) -> list[Run]:
    """``streams`` cameras at once, each its own stream."""
    runs: list[Run] = [Run()] * streams
    threads = []
    for i in range(streams):

        def one(i: int = i) -> None:
            runs[i] = camera(url, frames[i * 7 :] + frames[: i * 7], fps, count)

        threads.append(threading.Thread(target=one))
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return runs


def rss_series(url: str, pid: int, frames: list[bytes], fps: float, count: int) -> tuple[list[float], Run]:
    """The service's resident MB after every 500th of ``count`` frames sent at ``fps``."""
    from harness.service import resident_mb

    series: list[float] = []
    every = max(1, count // 10)

    def sample(seq: int) -> None:
        if seq % every == 0:
            series.append(resident_mb(pid))

    return series, camera(url, frames, fps, count, on_sent=sample, depth_encoding="raw16")


def sensor_depths() -> list[np.ndarray]:
    depths = []
    for n in TEST_FRAMES:
        mm = np.asarray(Image.open(SEVEN_SCENES / f"frame-{n:06d}.depth.png"), dtype=np.float64)
        depths.append(np.where(mm < 65535, mm / 1000, 0))
    return depths


def played(url: str, frames: list[bytes], smooth: str) -> tuple[list[np.ndarray], Intrinsics]:
    """Frames 850-999 in order through one lockstep stream: each frame's depth, and the camera it reports."""
    depths = []
    with open_stream(url, depth_encoding="raw16", smooth=smooth) as ws:
        for frame in frames:
            ws.send(frame)
            header, (body,) = receive(ws)
            depths.append(raw_depth(header["payloads"][0], body))
    return depths, Intrinsics(**header["intrinsics"])


def scale_stabilised(depths: list[np.ndarray], weight: float) -> list[np.ndarray]:
    """A per-stream scale stabiliser: each frame's median depth pulled to a running mean of the medians
    (in log), the new frame's median weighted ``weight``; the depth scaled by the difference."""
    out, mean = [], None
    for depth in depths:
        median = float(np.log(np.median(depth[depth > 0])))
        mean = median if mean is None else weight * median + (1 - weight) * mean
        out.append(depth * np.exp(mean - median))
    return out


def temporally_filtered(depths: list[np.ndarray], alpha: float, delta: float) -> list[np.ndarray]:
    smoother = TemporalFilter(alpha, delta)
    return [smoother.apply(depth.astype(np.float32)).astype(np.float64) for depth in depths]


def played_live(url: str, frames: list[bytes], smooth: str, fps: float) -> tuple[list[int], list[np.ndarray]]:
    """Frames 850-999 sent at ``fps`` as a camera sends them: the frames answered (indices) and their depth."""
    answered: list[tuple[int, np.ndarray]] = []
    with open_stream(url, depth_encoding="raw16", smooth=smooth) as ws:

        def read() -> None:
            while True:
                header, (body,) = receive(ws)
                answered.append((header["seq"] - 1, raw_depth(header["payloads"][0], body)))
                if header["seq"] == len(frames):
                    return

        reader = threading.Thread(target=read)
        reader.start()
        start = time.perf_counter()
        for i, frame in enumerate(frames):
            time.sleep(max(0.0, start + i / fps - time.perf_counter()))
            ws.send(frame)
        reader.join()
    return [i for i, _ in answered], [d for _, d in answered]


def flicker_row(label: str, depths: list[np.ndarray], poses, k: Intrinsics, floor, sensor) -> str:
    served = sequence_flicker(depths, poses, k)
    scores = MetricAccumulator()
    for depth, truth in zip(depths, sensor, strict=True):
        scores.add(depth, truth, KINECT_DEPTH)
    return (
        f"| {label} | {served.relative:.4f} | {served.relative / floor.relative:.2f}x | "
        f"{served.scale_jitter:.4f} | {scores.result()['delta1']:.4f} |"
    )


def flicker_rows(url: str, frames: list[bytes]) -> list[str]:
    """Flicker and δ1 of the served depth, plain and through ``smooth=temporal``, against the sensor's own
    flicker; then the levers weighed for smoothing, each applied in order to the plain served depth."""
    poses = [read_pose(SEVEN_SCENES / f"frame-{n:06d}.pose.txt") for n in TEST_FRAMES]
    sensor = sensor_depths()
    floor = sequence_flicker(sensor, poses, KINECT_DEPTH)
    rows = [f"| the sensor's own depth (the floor) | {floor.relative:.4f} | 1.00x | {floor.scale_jitter:.4f} | — |"]
    plain, k = played(url, frames, "off")
    smoothed, _ = played(url, frames, "temporal")
    rows.append(flicker_row("served, smooth=off", plain, poses, k, floor, sensor))
    rows.append(flicker_row("served, smooth=temporal (alpha 0.4, delta 5%)", smoothed, poses, k, floor, sensor))
    at_sensor = [np.where(s > 0, d, 0.0) for d, s in zip(plain, sensor, strict=True)]
    label = "served, smooth=off, moved with the sensor's camera at the sensor's pixels"
    rows.append(flicker_row(label, at_sensor, poses, KINECT_DEPTH, floor, sensor))
    for smooth in ("off", "temporal"):
        kept, depths = played_live(url, frames, smooth, 30)
        label = f"served at 30 fps as a camera sends, smooth={smooth} ({len(kept)} of 150 answered)"
        chosen = [sensor[i] for i in kept]
        rows.append(flicker_row(label, depths, [poses[i] for i in kept], k, floor, chosen))
    for weight in (0.5, 0.3):
        label = f"lever: scale stabiliser, new median weighted {weight}"
        rows.append(flicker_row(label, scale_stabilised(plain, weight), poses, k, floor, sensor))
    for alpha, delta in ((0.2, 0.05), (0.4, 0.10)):
        label = f"lever: temporal filter, alpha {alpha}, delta {delta:.0%}"
        rows.append(flicker_row(label, temporally_filtered(plain, alpha, delta), poses, k, floor, sensor))
    return rows


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
    from cli.stream import STREAM_MAX_PIXELS, close_all, paced, run_stream
    from clients.sinks.bag import BagSink
    from clients.sinks.foxglove import FoxgloveSink
    from clients.sinks.ros2 import Ros2Sink
    from clients.sinks.ros_messages import RosMessages, Topics
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
        written = run_stream(
            replace(source, frames=let_go(source.frames)), url, sinks, {"stride": stride}, {}, STREAM_MAX_PIXELS
        ).written
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


def closed(url: str, result: T) -> T:
    """``result``, once the service has let go of every stream (the next row may open as many as it allows)."""
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        text = httpx.get(f"{url}/metrics", timeout=5).text
        if "\nrgb2cloud_streams_open 0.0" in text:
            break
        time.sleep(0.05)
    return result


def speed_row(label: str, run: Run) -> str:
    return (
        f"| {label} | {run.fps:.1f} | {run.percentile(50):.0f} | {run.percentile(95):.0f} | "
        f"{statistics.median(run.work):.0f} | {1 - len(run.latencies) / run.sent:.0%} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=20, help="each speed row's length")
    parser.add_argument("--fps", type=float, default=30, help="the camera rows' frame rate")
    parser.add_argument("--soak-frames", type=int, default=5000, help="frames sent while RSS is watched")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--outputs-only", action="store_true", help="only the rows streaming a recording to outputs")
    args = parser.parse_args()
    frames = jpegs()
    count = int(args.seconds * args.fps)
    env = {"bundled_registry": BUNDLED_REGISTRY, "model": "rgb2cloud-7scenes", "engine": "onnxruntime"}
    with running_service(threads=str(args.threads), precision="fp32", **env) as service:
        url = service.url
        lockstep(url, frames[:10], 2)  # warm
        outputs = closed(url, sink_rows(url))
        if args.outputs_only:
            print(outputs)
            return
        post_run = posts(url, frames, args.seconds)
        step_run = closed(url, lockstep(url, frames, args.seconds))
        png_run = closed(url, camera(url, frames, args.fps, count))
        raw_run = closed(url, camera(url, frames, args.fps, count, depth_encoding="raw16"))
        four = closed(url, cameras(url, frames, args.fps, count, 4))
        flicker = closed(url, flicker_rows(url, frames))
        rss, soak = rss_series(url, service.pid, frames, args.fps, args.soak_frames)
    report(args, post_run, step_run, png_run, raw_run, four)
    print(f"\nRSS MB every {args.soak_frames // 10} of {args.soak_frames} frames at {args.fps:g} fps")
    print(f"({len(soak.latencies)} answered): {', '.join(f'{mb:.0f}' for mb in rss)}")
    print("\n| depth, frames 850-999 as a stream | flicker (mean relative) | against the sensor | scale jitter | δ1 |")
    print("|---|---|---|---|---|")
    print("\n".join(flicker))
    print(f"\n{outputs}")


def report(args: argparse.Namespace, post_run: Run, step_run: Run, png_run: Run, raw_run: Run, four: list[Run]):
    """The speed table, and the issue's three ratios: stream against the work's rate, POST, and p95 / work."""
    print(f"Machine: {cpu_description()}; service threads {args.threads}; frames 640x480 JPEG\n")
    print("| client | answers/s | p50 ms | p95 ms | service ms per frame (median) | frames skipped |")
    print("|---|---|---|---|---|---|")
    print(speed_row("POST /depth back to back", post_run))
    print(speed_row("stream, lockstep, png16", step_run))
    print(speed_row(f"stream, camera at {args.fps:g} fps, png16", png_run))
    print(speed_row(f"stream, camera at {args.fps:g} fps, raw16", raw_run))
    merged = Run(sent=sum(r.sent for r in four))
    for run in four:
        merged.latencies += run.latencies
        merged.work += run.work
    merged.seconds = len(merged.latencies) / sum(run.fps for run in four)
    print(speed_row(f"4 streams, each a camera at {args.fps:g} fps (answers/s: all four)", merged))
    print("\nEach row against its own per-frame work (decode + inference + encode, from its own headers):\n")
    print("| client | per-frame work ms | its rate, 1000 / work | answers/s | share of that rate | p95 / work |")
    print("|---|---|---|---|---|---|")
    rows = (("POST /depth back to back", post_run), ("stream, lockstep", step_run), ("stream, camera", png_run))
    for label, run in rows:
        own = statistics.median(run.work)
        share, p95 = run.fps / (1000 / own), run.percentile(95) / own
        print(f"| {label} | {own:.0f} | {1000 / own:.1f} | {run.fps:.1f} | {share:.0%} | {p95:.2f}x |")
    generator = statistics.median(png_run.inference)
    print(f"\nThe generator alone (the camera row's inference stage): {generator:.0f} ms, {1000 / generator:.1f}/s.")
    print(f"One stream (camera) against POST back to back: {png_run.fps / post_run.fps:.2f}x.")


if __name__ == "__main__":
    main()
