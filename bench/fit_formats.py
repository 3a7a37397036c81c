"""Does the format a recording comes in change what fit makes of it? One site as folders and as a ROS 2 bag.

    python bench/fit_formats.py [--budget 5] [--markdown runs/bench-formats/table.md]

mosd-tabletop's 107 captures are written into a ROS 2 bag (sqlite3) as the RealSense ROS wrapper
records them (colour ``rgb8``, depth ``16UC1`` aligned to colour, a ``CameraInfo`` each, 30 fps,
depth stamped 3 ms after colour) with ``rosbags``' own writer. Both the folders layout and the
bag are fitted with the same budget and split: in time order the 45 ``learn*`` captures come
first, so ``--holdout 45-106 --gap 0`` holds out the 62 ``test*`` captures in both. Fit's own
held-out table is read from each published card.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from contract.card import load_card
from harness.recordings import write_aligned_bag
from trainer.machine import cpu_description

REPO = Path(__file__).resolve().parents[1]
SITE = REPO.parent / "shared" / "data" / "mosd-tabletop"
LICENCE = "mOSD (Richtsfeld et al., TU Wien): research use"
OUT = REPO / "runs" / "bench-formats"


def site_bag(path: Path) -> Path:
    """The site's captures in name order (learn* before test*) as a ROS 2 bag, written once."""
    if not path.exists():
        frames = [
            (
                np.asarray(Image.open(colour).convert("RGB")),
                np.asarray(Image.open(SITE / "depth" / f"{colour.stem}.png")),
            )
            for colour in sorted((SITE / "color").glob("*.jpg"))
        ]
        write_aligned_bag(path, "ros2", frames)
    return path


def fit(recording: Path, name: str, budget: float) -> Path:
    version = OUT / "registry" / name / "0.1.0"
    if not version.is_dir():
        args = [str(recording), "--holdout", "45-106", "--gap", "0", "--licence", LICENCE, "--name", name]
        args += ["--budget", f"{budget:g}", "--register", "no", "--registry", str(OUT / "registry")]
        args += ["--out", str(OUT / "runs" / name)]
        subprocess.run([sys.executable, "-m", "cli", "fit", *args], cwd=REPO, check=True)
    return version


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=float, default=5.0)
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    args = parser.parse_args()
    recordings = {"folders (color/, depth/, intrinsics.json)": SITE, "ROS 2 bag (sqlite3)": site_bag(OUT / "bag")}
    rows = []
    for i, (label, recording) in enumerate(recordings.items()):
        card = load_card(fit(recording, f"mosd-format-{i}-{args.budget:g}min", args.budget))
        own = card.metrics[0]
        rows.append(
            f"| {label} | {card.training.steps} | {own.images} | {own.delta1:.3f} | {own.rel:.3f} | "
            f"{own.pc_rmse_mean:.3f} |"
        )
    table = (
        f"Machine: {cpu_description()}. mosd-tabletop, {args.budget:g}-minute fits, held out: the 62 `test*` "
        "captures (fit's own table, from each card).\n\n"
        "| recording | steps | held-out frames | δ1 | REL | PC RMSE (m) |\n|---|---|---|---|---|---|\n"
        + "\n".join(rows)
        + "\n"
    )
    print(table)
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        command = f"python bench/fit_formats.py --budget {args.budget:g}"
        args.markdown.write_text(f"# A recording's format\n\nMade by `{command}`.\n\n{table}")


if __name__ == "__main__":
    main()
