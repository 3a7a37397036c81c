"""How far each engine and precision's depth is from ONNX Runtime fp32's on a version's check photos: the
figures the service's "same depth" check bounds (contract.runtime.disagreement), for choosing and stating the
bounds, and for seeing what the check photo does to them.

    python bench/same_depth.py weights/rgb2cloud-7scenes/0.9.0

Every engine and precision that runs on this CPU (OpenVINO fp32, bf16 only where the CPU has bf16 units,
int8 where the version has the graph) against ONNX Runtime fp32, at each photo's size and at twice it, as a
version is checked where it loads. The photos: the version's sample where it ships one, the fixed texture a
version without one is checked on (``app.loading.stand_in_photo``), and a blank photo, which no version is
checked on any more: on it instance norms divide by a near-zero spread.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

from app.loading import stand_in_photo
from contract.card import ONNX_FILE, load_card
from contract.engines import onnx_runner, runs
from contract.runtime import SAME_DEPTH_WITHIN, check_sizes, depth_agreement, disagreement


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("version", type=Path, help="a published version folder")
    args = parser.parse_args()

    from trainer.machine import cpu_description

    card = load_card(args.version)
    height, width = card.camera.height, card.camera.width
    shown = {"stand-in texture": stand_in_photo(height, width), "blank": np.zeros((height, width, 3), np.uint8)}
    if card.sample is not None:
        with Image.open(args.version / card.sample) as im:
            shown = {"sample": np.asarray(im.convert("RGB"))} | shown
    files = {"fp32": ONNX_FILE, "bf16": ONNX_FILE} | ({"int8": card.int8.file} if card.int8 else {})
    decode, multiple = card.depth_encoding.decode, card.input_multiple
    reference = onnx_runner("onnxruntime", args.version / ONNX_FILE, multiple, 0, "fp32")
    checked = [
        (name, seen, decode(reference.predict_raw(seen)))
        for name, photo in shown.items()
        for seen in check_sizes(photo)
    ]
    print(f"Machine: {cpu_description()}. {card.name} {card.version}, against ONNX Runtime fp32.\n")
    within = f"within {SAME_DEPTH_WITHIN:.2f}x"
    print(f"| engine | precision | photo | size | lost | median rel | {within} | median ratio | verdict |")
    print("|---|---|---|---|---|---|---|---|---|")
    for engine in ("onnxruntime", "openvino"):
        for precision, file in files.items():
            if engine == "onnxruntime" and precision == "fp32":
                continue  # the reference
            if why := runs(engine, precision):
                print(f"| {engine} | {precision} | — | — | — | — | — | — | not here: {why} |")
                continue
            runner = onnx_runner(engine, args.version / file, multiple, 0, precision)
            for name, seen, truth in checked:
                figures = depth_agreement(truth, decode(runner.predict_raw(seen)))
                verdict = disagreement(figures) or "the same depth"
                size = f"{seen.shape[1]}x{seen.shape[0]}"
                cells = f"{figures['median_rel']:.2%} | {figures['within']:.1%} | {figures['median_ratio']:.3f}"
                print(f"| {engine} | {precision} | {name} | {size} | {figures['lost']:.2%} | {cells} | {verdict} |")


if __name__ == "__main__":
    main()
