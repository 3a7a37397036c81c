"""Does the format a recording comes in change what fit makes of it? One site as folders, a ROS 2 bag, a phone export.

    python bench/fit_formats.py [--budget 5] [--markdown runs/bench-formats/table.md]

mosd-tabletop's 107 captures are written into a ROS 2 bag (sqlite3) as the RealSense ROS wrapper
records them (colour ``rgb8``, depth ``16UC1`` aligned to colour, a ``CameraInfo`` each, 30 fps,
depth stamped 3 ms after colour) with ``rosbags``' own writer, and into a Stray Scanner export
as an iPhone records it (the photos enlarged to a 1920x1440 video encoded with PyAV, depth at
the app's 256x192). All three are fitted with the same
budget and split: in time order the 45 ``learn*`` captures come first, so ``--holdout 45-106
--gap 0`` holds out the 62 ``test*`` captures in each. Fit's own held-out table is read from each
published card (scored against each recording's own depth).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from contract.card import load_card
from harness.fitting import bench_arguments, fit_once, report
from harness.recordings import MOSD_CAMERA, write_aligned_bag, write_stray_scanner
from trainer.machine import cpu_description

REPO = Path(__file__).resolve().parents[1]
SITE = REPO.parent / "shared" / "data" / "mosd-tabletop"
LICENCE = "mOSD (Richtsfeld et al., TU Wien): research use"
OUT = REPO / "runs" / "bench-formats"


def site_frames() -> list[tuple[np.ndarray, np.ndarray]]:
    """The site's captures in name order (learn* before test*): (rgb, depth in millimetres)."""
    colours = sorted((SITE / "color").glob("*.jpg"))
    return [
        (np.asarray(Image.open(c).convert("RGB")), np.asarray(Image.open(SITE / "depth" / f"{c.stem}.png")))
        for c in colours
    ]


def site_bag(path: Path) -> Path:
    """The site's captures in name order as a ROS 2 bag, written once."""
    if not path.exists():
        write_aligned_bag(path, "ros2", site_frames())
    return path


def site_scan(path: Path) -> Path:
    """The site's captures in name order as a Stray Scanner export (1920x1440 video, 256x192 depth), written once."""
    if not path.exists():
        video = (1920, 1440)
        frames = [(np.asarray(Image.fromarray(rgb).resize(video, Image.BICUBIC)), mm) for rgb, mm in site_frames()]
        write_stray_scanner(path, frames, MOSD_CAMERA.resized(*video))
    return path


def main() -> None:
    args = bench_arguments(__doc__)
    recordings = {
        "folders (color/, depth/, intrinsics.json)": SITE,
        "ROS 2 bag (sqlite3)": site_bag(OUT / "bag"),
        "Stray Scanner export (1920x1440 rgb.mp4, 256x192 depth)": site_scan(OUT / "scan-1920x1440"),
    }
    options = [*f"--holdout 45-106 --gap 0 --budget {args.budget:g} --register no".split(), "--licence", LICENCE]
    rows = []
    for i, (label, recording) in enumerate(recordings.items()):
        card = load_card(fit_once(recording, f"mosd-format-{i}-{args.budget:g}min", OUT, *options))
        own = card.metrics[0]
        rows.append(
            f"| {label} | {card.training.config['train']['steps']} | {card.training.steps} | {own.images} | "
            f"{own.delta1:.3f} | {own.rel:.3f} | "
            f"{own.pc_rmse_mean:.3f} |"
        )
    table = (
        f"Machine: {cpu_description()}. mosd-tabletop, {args.budget:g}-minute fits, held out: the 62 `test*` "
        "captures (fit's own table, from each card).\n\n"
        "| recording | steps planned | steps (the published checkpoint) | held-out frames | δ1 | REL | PC RMSE (m) |\n"
        "|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    report(table, args.markdown, "A recording's format", f"python bench/fit_formats.py --budget {args.budget:g}")


if __name__ == "__main__":
    main()
