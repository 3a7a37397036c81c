"""Does a recording's resolution change what fit makes of it? One site as recorded, and enlarged 2x.

    python bench/fit_scale.py [--budget 5] [--markdown runs/bench-scale/table.md]

mosd-tabletop's frames are written again at 1280x960 (colour bicubic, depth nearest, the
intrinsics scaled with them), as a higher-resolution camera of the same views would record
them. Both copies are fitted with the same budget and split (train on ``learn*``, hold out
``test*``), each from the bundled start, each in its own process. Then one service serves
both published models, and each recording's held-out photos are posted at their own size
with their own focal length (``fx`` in the query, as a user with a calibrated camera sends
it) and scored against their own depth, beside ``rgb2cloud evaluate``'s score of the same
version. Fit trains a large recording at a smaller scale; fit's table, evaluate and the
service all feed the model photos at that scale (``contract.resample``), so the three scores
should agree to the third decimal.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from contract.card import load_card
from contract.geometry import Intrinsics
from harness.fitting import bench_arguments, fit_once, report
from harness.service import ServedDepth, running_service
from recordings.frames import Frame
from trainer.config import DataSource
from trainer.data.sources import open_source
from trainer.evaluate import evaluate_frames, load_predictor
from trainer.machine import cpu_description

REPO = Path(__file__).resolve().parents[1]
SITE = REPO.parent / "shared" / "data" / "mosd-tabletop"
LICENCE = "mOSD (Richtsfeld et al., TU Wien): research use"
OUT = REPO / "runs" / "bench-scale"
NATIVE = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)  # ../shared/data/mosd-tabletop/intrinsics.json


def enlarged_copy(target: Path, factor: int) -> Intrinsics:
    """The site's frames ``factor`` times larger, in the folders layout; returns the copy's camera."""
    camera = NATIVE.resized(NATIVE.width * factor, NATIVE.height * factor)
    if (target / "intrinsics.json").is_file():
        return camera
    (target / "color").mkdir(parents=True, exist_ok=True)
    (target / "depth").mkdir(exist_ok=True)
    for colour in sorted((SITE / "color").glob("*.jpg")):
        size = (camera.width, camera.height)
        Image.open(colour).convert("RGB").resize(size, Image.BICUBIC).save(target / "color" / colour.name, quality=95)
        depth = Image.open(SITE / "depth" / f"{colour.stem}.png")
        Image.fromarray(np.asarray(depth.resize(size, Image.NEAREST), dtype=np.uint16)).save(
            target / "depth" / f"{colour.stem}.png"
        )
    intrinsics = {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy, "depth_scale": 1000.0}
    (target / "intrinsics.json").write_text(json.dumps(intrinsics))
    return camera


def held_out(root: Path) -> list[Frame]:
    """The recording's held-out ``test*`` captures, read as fit reads them."""
    reader = open_source(DataSource(format="folders", root=root, frames="test*"))
    return [reader[i] for i in range(len(reader))]


def evaluated(version: Path, frames: list[Frame]) -> dict:
    """``rgb2cloud evaluate``'s scores of a published version on ``frames`` (the same code, in process)."""
    result, _, _ = evaluate_frames(load_predictor(version), frames, min_m=0.1, max_m=10.0)
    return result


def main() -> None:
    args = bench_arguments(__doc__)

    enlarged = OUT / "mosd-tabletop-1280x960"
    recordings = {
        "640x480 (as recorded)": (SITE, NATIVE),
        "1280x960 (enlarged 2x)": (enlarged, enlarged_copy(enlarged, 2)),
    }
    names = {label: f"mosd-{k.width}x{k.height}-{args.budget:g}min" for label, (_, k) in recordings.items()}
    options = [*f"--holdout test* --gap 0 --budget {args.budget:g} --register no".split(), "--licence", LICENCE]
    versions = {label: fit_once(root, names[label], OUT, *options) for label, (root, _) in recordings.items()}
    rows = []
    with running_service(registry=str(OUT / "registry"), model=f"{names['640x480 (as recorded)']}:0.1.0") as service:
        for label, (root, _) in recordings.items():
            card = load_card(versions[label])
            frames = held_out(root)
            served_depth = ServedDepth(service.url, f"{card.name}:{card.version}")
            served, _, _ = evaluate_frames(served_depth, frames, min_m=0.1, max_m=10.0)
            evaluate = evaluated(versions[label], frames)
            own = card.metrics[0]
            trained = f"{card.camera.width}x{card.camera.height}, fx {card.camera.fx:.1f}"
            rows.append(
                f"| {label} | {trained} | {card.training.steps} | {own.delta1:.4f} / {own.rel:.4f} | "
                f"{evaluate['delta1']:.4f} / {evaluate['rel']:.4f} | "
                f"{served['delta1']:.4f} / {served['rel']:.4f} | {', '.join(sorted(served_depth.focal_ratios))} |"
            )
    table = (
        f"Machine: {cpu_description()}. mosd-tabletop, {args.budget:g}-minute fits, 62 held-out `test*` captures.\n\n"
        "| recording | card camera (trained at) | steps (the published checkpoint) | fit's table δ1 / REL | "
        "evaluate δ1 / REL | served δ1 / REL | X-Focal-Ratio |\n"
        "|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    report(table, args.markdown, "A recording's resolution", f"python bench/fit_scale.py --budget {args.budget:g}")


if __name__ == "__main__":
    main()
