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
import tempfile
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from serving import DEFAULT_IMAGE, machine, median_ms

from contract.runtime import OnnxGenerator
from trainer.config import load_config
from trainer.export import export_onnx
from trainer.inference import InferenceGraph
from trainer.networks import GlobalGenerator

CONFIGS_DIR = Path(__file__).resolve().parents[1] / "configs"
SHIPPED = CONFIGS_DIR / "rgb2cloud-7scenes-0.8.0.yaml"

#: (label, config, overrides): the bundled model's network alone first, the ratio column's reference.
CONFIGS = [
    (
        "bundled shape: 16 filters, 3 downsamplings, 6 dilated blocks, half resolution, no median",
        SHIPPED,
        ["inference.median_radius=0"],
    ),
    (
        "bundled shape at full resolution (work_scale 1), no median",
        SHIPPED,
        ["generator.work_scale=1", "inference.median_radius=0"],
    ),
    (
        "bundled shape, 3x3 convolution then bilinear 2x upsampler (0.9.0), no median",
        SHIPPED,
        ["generator.upsampler=bilinear", "inference.median_radius=0"],
    ),
    (
        "bundled shape, pixel-shuffle upsampler (ICNR), no median",
        SHIPPED,
        ["generator.upsampler=shuffle", "inference.median_radius=0"],
    ),
    (
        "bundled shape, resize-then-convolution upsampler, no median",
        SHIPPED,
        ["generator.upsampler=resize", "inference.median_radius=0"],
    ),
    ("paper size: 32 filters, 4 downsamplings, 9 blocks, full resolution", CONFIGS_DIR / "7scenes-paper.yaml", []),
    *(
        (
            f"bundled shape, its output refined by a colour-weighted median of {2 * r + 1}x{2 * r + 1} taps",
            SHIPPED,
            [f"inference.median_radius={r}"],
        )
        for r in (1, 2)  # its cost depends on the taps only, not on their spacing or sigma; 2 is the bundled model
    ),
]


def multiply_adds(graph: torch.nn.Module, rgb: np.ndarray) -> int:
    """The convolutions' multiply-adds for one photo: each output value costs its kernel's taps over its inputs."""
    total = 0

    def count(module: torch.nn.Module, inputs: tuple[torch.Tensor, ...], output: torch.Tensor) -> None:
        nonlocal total
        taps = module.weight[0].numel() if isinstance(module, torch.nn.Conv2d) else module.weight[:, 0].numel()
        values = output.numel() if isinstance(module, torch.nn.Conv2d) else inputs[0].numel() // inputs[0].shape[1]
        total += values * taps * (1 if isinstance(module, torch.nn.Conv2d) else module.out_channels)

    convolutions = [m for m in graph.modules() if isinstance(m, torch.nn.Conv2d | torch.nn.ConvTranspose2d)]
    hooks = [m.register_forward_hook(count) for m in convolutions]
    with torch.no_grad():
        graph(torch.from_numpy(rgb.transpose(2, 0, 1).astype(np.float32)[None] / 127.5 - 1))
    for hook in hooks:
        hook.remove()
    return total


def measure(
    config: Path, overrides: list[str], rgb: np.ndarray, threads: int, repeats: int
) -> tuple[int, float, float, float]:
    """(weights, G multiply-adds, ONNX MB, median ms) of the config's generator, untrained."""
    run = load_config(config, overrides)
    graph = InferenceGraph(GlobalGenerator(run.generator), run.inference).eval()
    weights = sum(p.numel() for p in graph.parameters())
    macs = multiply_adds(graph, rgb) / 1e9
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "generator.onnx"
        export_onnx(graph, path)
        size_mb = path.stat().st_size / 1e6
        runner = OnnxGenerator(path, graph.input_multiple, threads)
        ms = median_ms(lambda: runner.predict_raw(rgb), repeats)
    return weights, macs, size_mb, ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--image", type=Path, default=DEFAULT_IMAGE)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    args = parser.parse_args()

    rgb = np.asarray(Image.open(args.image).convert("RGB").resize((640, 480)))
    rows = [(label, *measure(path, extra, rgb, args.threads, args.repeats)) for label, path, extra in CONFIGS]
    ref, ref_macs = rows[0][4], rows[0][2]
    lines = [
        f"| {label} | {w / 1e6:.2f} M | {macs:.2f} ({macs / ref_macs:.2f}x) | {mb:.1f} | {ms:.0f} | {ms / ref:.2f}x |"
        for label, w, macs, mb, ms in rows
    ]
    table = (
        f"Machine: {machine()}; ONNX Runtime on {args.threads} threads, median of {args.repeats}, 640x480.\n\n"
        "| generator | weights | G multiply-adds | ONNX MB | median ms | vs bundled |\n|---|---|---|---|---|---|\n"
        + "\n".join(lines)
        + "\n"
    )
    print(table)
    if args.markdown:
        command = f"python bench/generator_size.py --threads {args.threads} --repeats {args.repeats}"
        command += f" --markdown {args.markdown}"
        args.markdown.write_text(f"# Generator size and speed by config\n\nMade by `{command}`.\n\n{table}")


if __name__ == "__main__":
    main()
