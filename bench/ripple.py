"""The decoder's ripple in served depth, for each bundled version: spectral peaks, and a flat surface's point cloud.

    python bench/ripple.py [--versions 0.8.1 0.9.0] [--checkpoints RUN/checkpoints/last.pt ...]
                           [--frames 850-999:10] [--render docs/quality]

Each version runs in the real service (uvicorn, 127.0.0.1); its ``/depth`` of every 10th 7-Scenes test
frame (15 frames, 640x480) is the input. ``lab.ripple.ripple_peaks`` gives each period's spectral power
over its neighbourhood's, along y and along x: about 1 without ripple, as the ground-truth depth of the
same frames shows (its row). The bundled generators run at half the photo's resolution (``work_scale``
2), so the three 2x decoder stages' periods of 2, 4 and 8 network pixels are 4, 8 and 16 photo pixels.
``--checkpoints`` adds training checkpoints, run in process (eager PyTorch, the inference graph export
writes), so a run can be checked for ripple before it is published. ``--render`` writes, for each
version, frame 900's served depth as a surface lit by its normals (the point cloud's shape seen from
the camera): the wall, the table and the cabinet fronts are flat, and ripple shows on them as a grid of
stripes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from contract.geometry import Intrinsics
from harness.service import served_depths
from lab.ripple import ripple_peaks

REPO = Path(__file__).resolve().parents[1]
SEVEN_SCENES = REPO.parent / "shared" / "data" / "7scenes-redkitchen"
PERIODS = (2, 4, 8, 16)
RENDERED_FRAME = 900


def photos(frames: list[int]) -> list[Path]:
    return [SEVEN_SCENES / f"frame-{frame:06d}.color.jpg" for frame in frames]


def checkpoint_depths(checkpoint: Path, frames: list[int]) -> list[np.ndarray]:
    """Each frame's depth (metres) from a checkpoint's inference graph in eager PyTorch, at its working size."""
    import torch

    from contract.codec import rgb_to_input
    from trainer.checkpoint import load_graph

    graph, weights = load_graph(checkpoint)
    depths = []
    with torch.no_grad():
        for photo in photos(frames):
            rgb = np.asarray(Image.open(photo).convert("RGB"))
            output = graph(torch.from_numpy(rgb_to_input(rgb)))[0, 0].numpy()
            depths.append(weights.config.depth.decode(output))
    return depths


def truth_depths(frames: list[int]) -> list[np.ndarray]:
    depths = []
    for frame in frames:
        raw = np.asarray(Image.open(SEVEN_SCENES / f"frame-{frame:06d}.depth.png"), dtype=np.float64)
        depths.append(np.where(raw == 65535, 0, raw) / 1000)
    return depths


def row(label: str, depths: list[np.ndarray]) -> str:
    along_y, along_x = ripple_peaks(depths, 0, PERIODS), ripple_peaks(depths, 1, PERIODS)
    return f"| {label} | " + " | ".join(f"{v:.1f}" for v in [*along_y.values(), *along_x.values()]) + " |"


def shaded(depth: np.ndarray, camera: Intrinsics) -> np.ndarray:
    """Each pixel's surface lit from the upper left (grey levels from its normal): a ripple is stripes."""
    v, u = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]]
    points = np.stack([(u - camera.cx) / camera.fx * depth, (v - camera.cy) / camera.fy * depth, depth], -1)
    normal = np.cross(np.gradient(points, axis=1), np.gradient(points, axis=0))
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True) + 1e-12
    light = np.array([-0.35, -0.45, 0.82]) / np.linalg.norm([-0.35, -0.45, 0.82])
    grey = np.clip(normal @ light, 0, 1) * 220 + 30
    return np.repeat(grey[..., None], 3, axis=-1).astype(np.uint8)


def render(version: str, depth: np.ndarray, out: Path) -> Path:
    """Frame ``RENDERED_FRAME``'s served depth as a surface lit by its normals, as a PNG (no dataset pixels in it:
    the photo stays out, as 7-Scenes' licence asks)."""
    camera = Intrinsics(530.0, 530.0, 314.5, 239.0, 640, 480)  # the bundled versions' card camera
    path = out / f"ripple-{version}.png"
    Image.fromarray(shaded(depth, camera)).save(path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--versions", nargs="*", default=["0.8.1", "0.9.0"], help="bundled versions to serve")
    parser.add_argument("--checkpoints", type=Path, nargs="*", default=[], help="training checkpoints to add")
    parser.add_argument("--frames", default="850-999:10", help="FIRST-LAST:STEP of the 7-Scenes test frames")
    parser.add_argument("--render", type=Path, help="write each version's side view of a point cloud here")
    args = parser.parse_args()
    span, _, step = args.frames.partition(":")
    first, last = (int(v) for v in span.split("-"))
    frames = list(range(first, last + 1, int(step or 1)))
    periods = " | ".join(f"{p} px" for p in PERIODS)
    lines = [
        f"Spectral power at each period over its neighbourhood's, summed over {len(frames)} frames "
        f"({args.frames}) of /depth: about 1 means no ripple.",
        "",
        f"| depth | along y: {periods} | along x: {periods} |",
        "|---|" + "---|" * 2 * len(PERIODS),
        row("ground truth (Kinect)", truth_depths(frames)),
    ]
    for version in args.versions:
        depths = served_depths(f"rgb2cloud-7scenes:{version}", photos(frames))
        lines.append(row(f"rgb2cloud-7scenes {version}", depths))
        if args.render:
            args.render.mkdir(parents=True, exist_ok=True)
            print(f"wrote {render(version, depths[frames.index(RENDERED_FRAME)], args.render)}")
    for checkpoint in args.checkpoints:
        lines.append(row(f"{checkpoint} (eager)", checkpoint_depths(checkpoint, frames)))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
