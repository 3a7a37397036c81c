"""A fit's checkpoints on its own held-out frames: which one fit publishes matters.

    python bench/fit_checkpoints.py RUN_FOLDER [CHECKPOINT ...]    # default: best.pt and last.pt

RUN_FOLDER is a fit's run folder (``runs/fit/NAME``, or a lever's under ``runs/bench-levers/runs/``): its
``holdout.csv`` and ``train/checkpoints/``. Each checkpoint is scored on the held-out frames as fit's own table
scores them (ground truth 0.1-10 m, pixel to pixel, no median scaling), with the step it was saved at.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from trainer.checkpoint import load_checkpoint
from trainer.config import DataSource
from trainer.data.sources import open_source
from trainer.evaluate import evaluate_frames, load_predictor


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a fit's run folder")
    parser.add_argument("checkpoints", nargs="*", default=["best.pt", "last.pt"])
    args = parser.parse_args()
    frames = open_source(DataSource(format="csv", root=args.run / "holdout.csv"))
    print(f"{args.run.name}: {len(frames)} held-out frames\n")
    print("| checkpoint | step | δ1 | REL |\n|---|---|---|---|")
    for name in args.checkpoints:
        path = args.run / "train" / "checkpoints" / name
        if not path.is_file():
            print(f"| {name} | not saved | | |")
            continue
        step = load_checkpoint(path).step
        result, _, _ = evaluate_frames(load_predictor(path), frames, min_m=0.1, max_m=10.0)
        print(f"| {name} | {step} | {result['delta1']:.3f} | {result['rel']:.3f} |", flush=True)


if __name__ == "__main__":
    main()
