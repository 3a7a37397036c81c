"""int8 choices, each measured: calibration method and which nodes stay fp32, on the kitchen and a fitted site.

    python bench/int8.py --site-model runs/bench-fit/registry/aims-lab-default-30min/0.1.0 \
        [--choices METHOD:FP32_NODES:QUANTISED:WEIGHTS ...] [--frames 20] [--markdown FILE]

A choice is a calibration method (minmax, entropy, percentile), the nodes left in fp32 (none,
ends, ends+upsampling), the kinds of node quantised (all, convolutions) and the weights' bits
(8bit, or 7bit: ``reduce_range``, which cannot saturate on CPUs without VNNI): ``trainer.quantize``.
For each choice the published versions' ONNX graphs are quantised,
calibrated on ``--frames`` of each model's own training frames, then scored as the
service runs them: the bundled kitchen model on RedKitchen test frames 850-999 read at
the colour camera, and the fitted site model on its held-out frames. The generator's
time at 640x480 is a median over ``--repeats`` runs, fp32 and int8 interleaved in one
process, so read the ratio.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from functools import partial
from pathlib import Path

import numpy as np

from contract.card import ONNX_FILE, load_card
from contract.geometry import ColourCamera
from contract.runtime import OnnxGenerator
from harness.fitting import REPO, report
from harness.timing import interleaved_ms
from trainer.config import DataSource
from trainer.data.sources import open_source
from trainer.evaluate import Predictor, evaluate_frames
from trainer.quantize import KEEP, METHODS, OPS, calibration_frames, quantize_generator

KITCHEN = REPO / "weights" / "rgb2cloud-7scenes" / "0.8.1"
KITCHEN_TEST = DataSource(
    format="7scenes", root=REPO.parent / "shared" / "data" / "7scenes-redkitchen", frames="850-999"
)
KITCHEN_COLOUR = ColourCamera(fx=530, fy=530, cx=314.5, cy=239, baseline_m=0.009)


#: What was measured: ONNX Runtime's defaults first (minmax, everything quantised), then one change at a time.
CHOICES = [
    ("minmax", "none", "all", "8bit"),
    ("percentile", "none", "all", "8bit"),
    ("percentile", "none", "convolutions", "8bit"),
    ("minmax", "ends", "all", "8bit"),
    ("entropy", "ends", "all", "8bit"),
    ("percentile", "ends", "all", "8bit"),
    ("percentile", "ends+upsampling", "all", "8bit"),
    ("minmax", "ends", "convolutions", "8bit"),
    ("percentile", "ends", "convolutions", "8bit"),
    ("percentile", "none", "all", "7bit"),
]
WEIGHTS = ("8bit", "7bit")


def choice(text: str) -> tuple[str, str, str, str]:
    """``METHOD:FP32_NODES:QUANTISED:WEIGHTS`` -> its four parts, each checked."""
    parts = text.split(":")
    if (
        len(parts) != 4
        or parts[0] not in METHODS
        or parts[1] not in KEEP
        or parts[2] not in OPS
        or parts[3] not in WEIGHTS
    ):
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected METHOD:FP32_NODES:QUANTISED:WEIGHTS, e.g. percentile:none:all:7bit"
        )
    return parts[0], parts[1], parts[2], parts[3]


def score(version: Path, onnx_file: Path, test: DataSource, colour: ColourCamera | None) -> dict:
    """δ1 and REL of one graph of a version, run as the service runs it (at the card's camera size)."""
    card = load_card(version)
    runner = OnnxGenerator(onnx_file, card.input_multiple)
    predict = Predictor(lambda rgb: card.depth_encoding.decode(runner.predict_raw(rgb)), card.camera, onnx_file.name)
    result, _, _ = evaluate_frames(predict, open_source(test), min_m=0.1, max_m=10.0, colour_camera=colour)
    return {"delta1": result["delta1"], "rel": result["rel"]}


def generator_ms(files: list[Path], multiple: int, repeats: int) -> list[float]:
    """Median ms of each graph on one 640x480 photo, the graphs interleaved so load hits them alike."""
    runners = [OnnxGenerator(f, multiple, os.cpu_count() or 1) for f in files]  # the service's threads
    rgb = np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    calls = {str(i): partial(runner.predict_raw, rgb) for i, runner in enumerate(runners)}
    return list(interleaved_ms(calls, repeats).values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--site-model", type=Path, required=True, help="a fitted version folder (its fit.json beside)")
    parser.add_argument(
        "--choices", nargs="+", type=choice, default=CHOICES, help="METHOD:FP32_NODES:QUANTISED:WEIGHTS"
    )
    parser.add_argument("--frames", type=int, default=20, help="calibration frames per model")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()

    from trainer.machine import cpu_description

    site_card = load_card(args.site_model)
    site_run = Path(site_card.training.config["train"]["out_dir"]).parent
    holdout = DataSource(format="csv", root=site_run / "holdout.csv")
    models = {
        "kitchen 0.8.1 (test 850-999, colour camera)": (KITCHEN, KITCHEN_TEST, KITCHEN_COLOUR),
        f"{site_card.name} (held out)": (args.site_model, holdout, None),
    }
    choices: list[tuple[str, str | None, str, str, str]] = [("fp32", None, "", "", "")] + [
        (f"int8: {method}, fp32 nodes {keep}, quantised {ops}, {bits} weights", method, keep, ops, bits)
        for method, keep, ops, bits in args.choices
    ]
    rows: dict[str, list[str]] = {label: [] for label, *_ in choices}
    with tempfile.TemporaryDirectory() as tmp:
        for index, (model_label, (version, test, colour)) in enumerate(models.items()):
            card = load_card(version)
            readers = [open_source(DataSource.model_validate(s)) for s in card.training.config["data"]["train"]]
            photos = calibration_frames(readers, args.frames, card.camera)
            files = []
            for label, method, keep, ops, bits in choices:
                path = version / ONNX_FILE
                if method:
                    path = Path(tmp) / f"{index}-{method}-{keep}-{ops}-{bits}.onnx"
                    seven = bits == "7bit"
                    quantize_generator(version / ONNX_FILE, path, photos, card.input_multiple, method, keep, ops, seven)
                files.append(path)
                scores = score(version, path, test, colour)
                rows[label].append(f"{scores['delta1']:.3f} / {scores['rel']:.3f}")
                print(model_label, label, rows[label][-1], flush=True)
            if index == 0:
                times = generator_ms(files, card.input_multiple, args.repeats)
    for (label, *_), ms in zip(choices, times, strict=True):
        rows[label].append(f"{ms:.1f} ms ({times[0] / ms:.2f}x)")
    header = " | ".join(models)
    table = (
        f"Machine: {cpu_description()}. Calibrated on {args.frames} of each model's training frames; "
        "δ1 / REL as the service runs each graph; generator time at 640x480 on every core, median of "
        f"{args.repeats}, against fp32 in the same run.\n\n| graph | {header} | generator |\n|---|---|---|---|\n"
        + "\n".join(f"| {label} | {' | '.join(cells)} |" for label, cells in rows.items())
        + "\n"
    )
    named = " ".join(":".join(c) for c in args.choices)
    command = f"python bench/int8.py --site-model {args.site_model} --choices {named} --frames {args.frames}"
    report(table, args.markdown, "int8 choices", command)


if __name__ == "__main__":
    main()
