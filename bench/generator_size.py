"""Generator size and CPU speed by training config: what a config would cost to serve.

    python bench/generator_size.py [--threads 2] [--repeats 10] [--markdown docs/benchmarks-generators.md]

A generator's ONNX file size and ONNX Runtime latency depend on its shape, not its
weights, so each config's generator is built untrained, exported the way
``rgb2cloud export`` exports it, and timed on one 640x480 photo. That prices a
config against the bundled model's limits (300 ms per image on 2 cores, 20 MB)
before, or without, training it: the paper-size model in particular was trained
on a leased GPU whose checkpoint could not be kept. Rows are medians of one run
on one machine, so read the ratio column.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from serving import DEFAULT_IMAGE, machine, median_ms  # noqa: E402

from model.config import load_config  # noqa: E402
from model.export import export_onnx  # noqa: E402
from model.networks import GlobalGenerator  # noqa: E402
from model.runtime import OnnxGenerator  # noqa: E402

#: (label, config, overrides): the bundled model's shape first, the ratio column's reference.
CONFIGS = [
    (
        "bundled 0.5.0's shape: 16 filters, 3 downsamplings, 6 dilated blocks, half resolution",
        "configs/7scenes-default.yaml",
        ["generator.dilations=[1, 2, 4, 8, 4, 2]"],
    ),
    (
        "bundled shape at full resolution (work_scale 1)",
        "configs/7scenes-default.yaml",
        ["generator.dilations=[1, 2, 4, 8, 4, 2]", "generator.work_scale=1"],
    ),
    ("paper size: 32 filters, 4 downsamplings, 9 blocks, full resolution", "configs/7scenes-paper.yaml", []),
    *(
        (
            f"bundled shape, its output refined by a colour-weighted median of {2 * r + 1}x{2 * r + 1} taps",
            "configs/7scenes-default.yaml",
            ["generator.dilations=[1, 2, 4, 8, 4, 2]", f"generator.median_radius={r}"],
        )
        for r in (1, 2)  # its cost depends on the taps only, not on their spacing or sigma
    ),
    (
        "bundled shape, 5x5-tap median, then colour-guided upsampling",
        "configs/7scenes-default.yaml",
        [
            "generator.dilations=[1, 2, 4, 8, 4, 2]",
            "generator.median_radius=2",
            "generator.upsample_sigma=0.2",  # any sigma > 0 turns it on; its cost does not depend on it
        ],
    ),
]


def measure(
    config: Path, overrides: list[str], rgb: np.ndarray, threads: int, repeats: int
) -> tuple[int, float, float]:
    """(weights, ONNX MB, median ms) of the config's generator, untrained."""
    generator = GlobalGenerator(load_config(config, overrides).generator)
    weights = sum(p.numel() for p in generator.parameters())
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "generator.onnx"
        export_onnx(generator, path)
        size_mb = path.stat().st_size / 1e6
        runner = OnnxGenerator(path, generator.config.input_multiple, threads)
        ms = median_ms(lambda: runner.predict_raw(rgb), repeats)
    return weights, size_mb, ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--image", type=Path, default=DEFAULT_IMAGE)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    args = parser.parse_args()

    rgb = np.asarray(Image.open(args.image).convert("RGB").resize((640, 480)))
    rows = [(label, *measure(REPO / path, extra, rgb, args.threads, args.repeats)) for label, path, extra in CONFIGS]
    ref = rows[0][3]
    lines = [f"| {label} | {w / 1e6:.2f} M | {mb:.1f} | {ms:.0f} | {ms / ref:.1f}x |" for label, w, mb, ms in rows]
    table = (
        f"Machine: {machine()}; ONNX Runtime on {args.threads} threads, median of {args.repeats}, 640x480.\n\n"
        "| generator | weights | ONNX MB | median ms | vs bundled |\n|---|---|---|---|---|\n" + "\n".join(lines) + "\n"
    )
    print(table)
    if args.markdown:
        command = f"python bench/generator_size.py --threads {args.threads} --repeats {args.repeats}"
        command += f" --markdown {args.markdown}"
        args.markdown.write_text(f"# Generator size and speed by config\n\nMade by `{command}`.\n\n{table}")


if __name__ == "__main__":
    main()
