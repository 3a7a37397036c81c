"""Stream benchmark: live depth over ``/v1/stream`` against back-to-back POST /depth, in one run.

    python bench/stream.py [--seconds 20] [--soak-frames 5000] [--threads 2]
    python bench/stream.py --models rgb2cloud-7scenes:0.9.1 my-room [--registry DIR]   # models side by side
    python bench/stream.py --stages [--models ...] [--engine auto --precision auto]   # where a frame's time goes

One service (the bundled default; ONNX Runtime fp32 unless --engine and --precision say) on 127.0.0.1
answers every row; the client runs on the same machine. Frames are the 7-Scenes RedKitchen test frames
850-999, 640x480 JPEGs, cycled.
"Camera" rows send at a camera's rate whatever the service does, as a webcam would; "lockstep" sends
the next frame when the last is answered. Latency is from a frame's send to its answer's last byte.
The per-frame work is the service's own decode + inference + encode (the stages each header reports).
The flicker table plays frames 850-999 in order as a stream (``harness.flicker``, docs/quality.md).
``--stages`` prints each model's stage table instead (``bench/stream_stages.py``).
``--models`` compares models instead (a fitted site model against the one it would replace): one service
serves them all, and each answers a lockstep row and a camera row, in two rounds in opposite orders.
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import httpx
import numpy as np
from PIL import Image
from stream_outputs import SEVEN_SCENES, TEST_FRAMES, sink_rows
from stream_stages import stage_report

from app.temporal import TemporalFilter
from clients.stream import open_stream, raw_depth, receive
from contract.geometry import Intrinsics
from harness.flicker import read_pose, sequence_flicker
from harness.service import BUNDLED_REGISTRY, running_service, server_timing
from trainer.machine import cpu_description
from trainer.metrics import MetricAccumulator

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
    parser.add_argument("--models", nargs="+", help="compare these models (NAME or NAME:VERSION) instead")
    parser.add_argument("--registry", type=Path, help="where the --models not bundled are published")
    parser.add_argument("--stages", action="store_true", help="where each frame's time goes, stage by stage")
    parser.add_argument("--engine", default="onnxruntime", help="the service's RGB2CLOUD_ENGINE")
    parser.add_argument("--precision", default="fp32", help="the service's RGB2CLOUD_PRECISION")
    args = parser.parse_args()
    frames = jpegs()
    count = int(args.seconds * args.fps)
    if args.stages:
        stages(args, frames)
        return
    if args.models:
        model_rows(args, frames, count)
        return
    env = {"bundled_registry": BUNDLED_REGISTRY, "model": "rgb2cloud-7scenes", "engine": args.engine}
    with running_service(threads=str(args.threads), precision=args.precision, **env) as service:
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


def stages(args: argparse.Namespace, frames: list[bytes]) -> None:
    """The stage table of each of ``--models`` (the bundled default without it), one service serving them all."""
    models = args.models or ["rgb2cloud-7scenes"]
    env = {"bundled_registry": BUNDLED_REGISTRY, "model": models[0], "engine": args.engine}
    env |= {"max_loaded": str(max(2, len(models)))} | ({"registry": str(args.registry)} if args.registry else {})
    print(f"Machine: {cpu_description()}; service threads {args.threads}; engine {args.engine}, precision ", end="")
    print(f"{args.precision}; one lockstep stream, 7-Scenes frames 640x480 JPEG, {args.seconds:g} s a table\n")
    with running_service(threads=str(args.threads), precision=args.precision, **env) as service:
        for model in models:
            lockstep(service.url, frames[:10], 2, model=model)  # loaded and warm before any table is timed
        print(stage_report(service.url, frames, args.seconds, models, closed))


def model_rows(args: argparse.Namespace, frames: list[bytes], count: int) -> None:
    """Each model's lockstep and camera rows from one service, in two rounds (A B, then B A) so that a machine
    growing busier or quieter shows as a difference between rounds, not between models."""
    env = {"bundled_registry": BUNDLED_REGISTRY, "model": args.models[0], "engine": args.engine}
    env |= {"max_loaded": str(len(args.models))} | ({"registry": str(args.registry)} if args.registry else {})
    print(f"Machine: {cpu_description()}; service threads {args.threads}; {args.engine} {args.precision}; ", end="")
    print("frames 640x480 JPEG\n")
    print("| round | model | lockstep answers/s | p50 ms | p95 ms | generator ms | camera answers/s | p95 ms |")
    print("|---|---|---|---|---|---|---|---|")
    with running_service(threads=str(args.threads), precision=args.precision, **env) as service:
        url = service.url
        for model in args.models:
            lockstep(url, frames[:10], 2, model=model)  # loaded and warm before any row is timed
        for round_, order in enumerate((args.models, args.models[::-1]), 1):
            for model in order:
                step = closed(url, lockstep(url, frames, args.seconds, model=model))
                cam = closed(url, camera(url, frames, args.fps, count, model=model))
                print(
                    f"| {round_} | {model} | {step.fps:.1f} | {step.percentile(50):.0f} | {step.percentile(95):.0f} | "
                    f"{statistics.median(step.inference):.0f} | {cam.fps:.1f} | {cam.percentile(95):.0f} |",
                    flush=True,
                )


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
