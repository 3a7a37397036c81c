"""How far each reduced precision's depth is from fp32's on a version's sample photo: the figures the
service's "same depth" check bounds (contract.runtime.disagreement), for choosing and stating the bounds.

    python bench/same_depth.py weights/rgb2cloud-7scenes/0.9.0

Every engine and precision that runs on this CPU (bf16 only where it has bf16 units) against ONNX Runtime
fp32, at the sample's size and at twice it, as a version is checked where it loads.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from contract.card import ONNX_FILE, load_card
from contract.engines import onnx_runner, runs
from contract.runtime import SAME_DEPTH_WITHIN, check_sizes, depth_agreement, disagreement


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("version", type=Path, help="a published version folder with an int8 graph and sample")
    args = parser.parse_args()

    from trainer.machine import cpu_description

    card = load_card(args.version)
    if card.int8 is None or card.sample is None:
        raise SystemExit(f"{args.version}: no int8 graph and sample photo to measure on")
    with Image.open(args.version / card.sample) as im:
        photos = check_sizes(np.asarray(im.convert("RGB")))
    files = {"fp32": ONNX_FILE, "bf16": ONNX_FILE, "int8": card.int8.file}
    decode, multiple = card.depth_encoding.decode, card.input_multiple
    reference = onnx_runner("onnxruntime", args.version / ONNX_FILE, multiple, 0, "fp32")
    truths = [decode(reference.predict_raw(p)) for p in photos]
    print(f"Machine: {cpu_description()}. {card.name} {card.version}, its sample photo against ONNX Runtime fp32.\n")
    within = f"within {SAME_DEPTH_WITHIN:.2f}x"
    print(f"| engine | precision | size | lost | median rel | {within} | median ratio | verdict |")
    print("|---|---|---|---|---|---|---|---|")
    for engine in ("onnxruntime", "openvino"):
        for precision in ("bf16", "int8"):
            if why := runs(engine, precision):
                print(f"| {engine} | {precision} | — | — | — | — | — | not here: {why} |")
                continue
            runner = onnx_runner(engine, args.version / files[precision], multiple, 0, precision)
            for photo, truth in zip(photos, truths, strict=True):
                figures = depth_agreement(truth, decode(runner.predict_raw(photo)))
                verdict = disagreement(figures) or "the same depth"
                height, width = photo.shape[:2]
                cells = f"{figures['median_rel']:.2%} | {figures['within']:.1%} | {figures['median_ratio']:.3f}"
                print(f"| {engine} | {precision} | {width}x{height} | {figures['lost']:.2%} | {cells} | {verdict} |")


if __name__ == "__main__":
    main()
