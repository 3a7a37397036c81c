"""A long phone recording: how long fit reads it before training, and how much it writes.

    python bench/long_recording.py [--seconds 120] [--fps 60] [--before CHECKOUT --before-seconds 20]

Writes a Stray Scanner export of ``--seconds`` at ``--fps`` (1920x1440 video, as current iPhones
record; real mOSD frames enlarged, each panned a little so no two are alike; 256x192 depth and
confidence), then times what fit does before its first training step that depends on the
recording's length: reading it, converting and writing the frames it keeps, and decoding each
written pair once to check it (``open_recording`` then ``readable``). It prints the time and the
disk the written frames take. With ``--before CHECKOUT`` (a checkout of another commit, e.g. a
``git worktree`` of the one before long recordings were capped), the same is timed there on a
``--before-seconds`` slice, in its own process, and extrapolated linearly to the whole recording.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

from harness.recordings import MOSD_CAMERA, STRAY_DEPTH_SIZE

REPO = Path(__file__).resolve().parents[1]
MOSD = REPO.parent / "shared" / "data" / "mosd-tabletop"
OUT = REPO / "runs" / "bench-long"
VIDEO = (1920, 1440)
#: What the timed process runs, in whichever checkout it is started: fit's reading and checks.
TIMED = """
import json, sys, time
from pathlib import Path
from recordings.formats import ReadOptions, open_recording
started = time.perf_counter()
recording = open_recording(Path(sys.argv[1]), None, ReadOptions(), Path(sys.argv[2]))
try:
    from trainer.fit.inspect import readable
    recording = readable(recording)
except ImportError:  # a checkout from before fit checked every pair
    pass
print(json.dumps({"seconds": time.perf_counter() - started, "pairs": len(recording.pairs)}))
"""


def write_export(root: Path, frames: int, fps: int) -> Path:
    """A Stray Scanner export of ``frames`` frames, streamed: never more than one frame in memory."""
    import av

    if (root / "odometry.csv").is_file():
        return root
    shutil.rmtree(root, ignore_errors=True)
    (root / "depth").mkdir(parents=True)
    (root / "confidence").mkdir()
    sources = sorted((MOSD / "color").glob("learn*.jpg"))
    camera = MOSD_CAMERA.resized(*VIDEO)
    big = (VIDEO[0] + 64, VIDEO[1] + 48)  # room to pan
    with av.open(str(root / "rgb.mp4"), "w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = *VIDEO, "yuv420p"
        stream.options = {"preset": "ultrafast", "crf": "18"}
        for i in range(frames):
            source = sources[(i // fps) % len(sources)]  # a new view every second, panned within it
            if i % fps == 0:
                image = Image.open(source).convert("RGB").resize(big, Image.Resampling.BILINEAR)
                depth = Image.open(MOSD / "depth" / f"{source.stem}.png")
                small = np.asarray(depth.resize(STRAY_DEPTH_SIZE, Image.Resampling.NEAREST), dtype=np.uint16)
                confidence = np.where(small > 0, 2, 0).astype(np.uint8)
            shift = i % fps
            view = image.crop((shift, shift // 2, shift + VIDEO[0], shift // 2 + VIDEO[1]))
            for packet in stream.encode(av.VideoFrame.from_image(view)):
                container.mux(packet)
            Image.fromarray(small).save(root / "depth" / f"{i:06d}.png")
            Image.fromarray(confidence).save(root / "confidence" / f"{i:06d}.png")
        for packet in stream.encode():
            container.mux(packet)
    k = camera
    (root / "camera_matrix.csv").write_text(f"{k.fx},0.0,{k.cx}\n0.0,{k.fy},{k.cy}\n0.0,0.0,1.0\n")
    rows = [f"{i / fps:.6f}, {i:06d}, 0, 0, 0, 0, 0, 0, 1" for i in range(frames)]
    (root / "odometry.csv").write_text("\n".join(["timestamp, frame, x, y, z, qx, qy, qz, qw", *rows]) + "\n")
    return root


def timed(checkout: Path, export: Path, scratch: Path) -> dict:
    """fit's reading and checks of ``export`` by the code in ``checkout``, in a fresh process."""
    shutil.rmtree(scratch, ignore_errors=True)
    command = [sys.executable, "-c", TIMED, str(export), str(scratch)]
    result = subprocess.run(command, cwd=checkout, capture_output=True, text=True, check=True)
    measured = json.loads(result.stdout.strip().splitlines()[-1])
    measured["disk_mb"] = sum(p.stat().st_size for p in scratch.rglob("*") if p.is_file()) / 1e6
    return measured


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=int, default=120)
    parser.add_argument("--fps", type=int, default=60)
    parser.add_argument("--before", type=Path, help="a checkout of the commit to compare with")
    parser.add_argument("--before-seconds", type=int, default=20)
    args = parser.parse_args()

    from trainer.machine import cpu_description

    frames = args.seconds * args.fps
    started = time.perf_counter()
    export = write_export(OUT / f"stray-{args.seconds}s-{args.fps}fps", frames, args.fps)
    print(f"export: {frames} frames in {time.perf_counter() - started:.0f} s", flush=True)
    rows = [("this checkout", timed(REPO, export, OUT / "scratch-now"), 1.0)]
    if args.before:
        part = args.before_seconds * args.fps
        sliced = write_export(OUT / f"stray-{args.before_seconds}s-{args.fps}fps", part, args.fps)
        rows.append(
            (
                f"{args.before} ({args.before_seconds} s slice, x{frames / part:g})",
                timed(args.before, sliced, OUT / "scratch-before"),
                frames / part,
            )
        )
    print(
        f"\nMachine: {cpu_description()}. A {args.seconds} s, {args.fps} fps Stray Scanner export ({frames} frames, "
        f"video {VIDEO[0]}x{VIDEO[1]} H.264), read as fit reads it.\n"
    )
    print("| code | pairs written | reading, writing, checking (s) | written frames (MB) |")
    print("|---|---|---|---|")
    for label, measured, factor in rows:
        print(
            f"| {label} | {measured['pairs'] * factor:.0f} | {measured['seconds'] * factor:.0f} | "
            f"{measured['disk_mb'] * factor:.0f} |"
        )


if __name__ == "__main__":
    main()
