"""Score a generator with the paper's metrics and write the reports people read.

Outputs in the chosen folder: ``metrics.json`` (everything, per image too),
``metrics.md`` (the paper's table with our row beside the paper's), the
Figure-8 curve ``pc_rmse_curve.png`` and ``samples.png`` (RGB | predicted | truth).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from model.card import ONNX_FILE, load_card, verify_files
from model.checkpoint import load_ensemble
from model.config import ColourCamera, GeneratorConfig
from model.data.frames import Frame
from model.data.transforms import resize_frame
from model.failures import FailureAccumulator
from model.metrics import METRIC_NAMES, MetricAccumulator, median_ratio, valid_mask
from model.registration import sample_at_colour
from model.runtime import OnnxGenerator, TorchModuleGenerator
from model.visualize import plot_pc_curve, sample_grid

#: The reference paper's Table 2 (TUM RGB-D) and its mean point-cloud RMSE on TUM.
PAPER_TUM = {
    "rel": 0.107,
    "rmse": 0.548,
    "log10": 0.047,
    "delta1": 0.942,
    "delta2": 0.984,
    "delta3": 0.990,
    "pc_rmse_mean": 0.420,
}
COLUMNS = (*METRIC_NAMES, "pc_rmse_mean")
HEADERS = ("REL", "RMSE (m)", "log10", "δ<1.25", "δ<1.25²", "δ<1.25³", "PC RMSE (m)")
LOWER_IS_BETTER = {"rel", "rmse", "log10", "pc_rmse_mean"}


def evaluate_frames(
    predict: Callable[[np.ndarray], np.ndarray],
    frames: Sequence[Frame],
    *,
    min_m: float,
    max_m: float,
    scale: float = 1.0,
    samples: int = 0,
    progress: bool = False,
    median_scaled: bool = False,
    where_fails: bool = False,
    colour_camera: ColourCamera | None = None,
) -> tuple[dict, list[dict], list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Predict every frame (resized by ``scale``) and average the per-image metrics.

    ``predict`` maps an HxWx3 uint8 image to HxW metres. Returns (the table row,
    per-image rows, up to ``samples`` evenly spaced (rgb, prediction, ground
    truth) triples for a sample grid).

    ``median_scaled`` adds a diagnostic beside the row, from the same predictions:
    the metrics after scaling each prediction by its ``median_ratio``
    (``result["median_scaled"]``) and that ratio's mean and standard deviation
    over the images (``result["median_ratio"]``; per image as ``median_ratio``).
    ``where_fails`` adds ``result["where_fails"]``: how the delta1 failures split
    between pixels near ground-truth depth steps and the rest (``model.failures``).
    ``colour_camera``: the ground truth is a depth camera's and the prediction the
    colour camera's (a model trained on registered depth); each ground-truth pixel
    is compared with the prediction at the colour pixel that sees the same point
    (``model.registration.sample_at_colour``), so every valid pixel still counts.
    """
    acc = MetricAccumulator(min_m=min_m, max_m=max_m)
    scaled = MetricAccumulator(min_m=min_m, max_m=max_m)
    failures = FailureAccumulator()
    per_image, grid = [], []
    keep = set(np.linspace(0, len(frames) - 1, samples).round().astype(int)) if samples else set()
    for i in tqdm(range(len(frames)), desc="evaluate", disable=not progress, unit="img"):
        frame = frames[i]
        if scale != 1.0:
            h, w = frame.depth.shape
            frame = resize_frame(frame, round(h * scale), round(w * scale))
        pred = predict(frame.rgb)
        if colour_camera is not None:
            pred = sample_at_colour(pred, frame.depth, frame.intrinsics, colour_camera.resized(scale))
        row = acc.add(pred, frame.depth, frame.intrinsics, frame.name)
        if row and (median_scaled or where_fails):
            valid = valid_mask(frame.depth, min_m, max_m)
            if median_scaled:
                row = {**row, "median_ratio": median_ratio(pred, frame.depth, valid)}
                scaled.add(pred * row["median_ratio"], frame.depth, frame.intrinsics, frame.name)
            if where_fails:
                failures.add(pred, frame.depth, valid)
        if row:
            per_image.append({"name": frame.name, **row})
        if i in keep:
            grid.append((frame.rgb, pred, frame.depth))
    result = acc.result()
    if median_scaled:
        ratios = [r["median_ratio"] for r in per_image]
        result["median_scaled"] = scaled.result()
        result["median_ratio"] = {"mean": float(np.mean(ratios)), "std": float(np.std(ratios))}
    if where_fails:
        result["where_fails"] = failures.result()
    return result, per_image, grid


def load_predictor(
    paths: Sequence[Path], run_as: dict[str, Any] | None = None
) -> tuple[Callable[[np.ndarray], np.ndarray], str]:
    """A depth predictor and a label from checkpoints (.pt) or one published version folder.

    A version folder is checked against its card (sha256) and, as exported, run the
    way the service runs it: ONNX Runtime, then the card's depth encoding. With
    ``run_as`` (``GeneratorConfig.run_as``: other inference settings for the same
    weights) a version runs eagerly from its TorchScript weights instead, as a
    checkpoint does. Several checkpoints run as one ``GeneratorEnsemble``, the mean
    of their outputs.
    """
    paths = [Path(p) for p in paths]
    if any(p.is_dir() for p in paths) and len(paths) > 1:
        raise ValueError(f"{paths}: a published version folder is scored alone, not averaged with others")
    if paths[0].is_dir() and not run_as:
        card = load_card(paths[0])
        verify_files(paths[0], card)
        runner = OnnxGenerator(paths[0] / ONNX_FILE, card.input_multiple)
        return (lambda rgb: card.depth_encoding.decode(runner.predict_raw(rgb))), f"{card.name} {card.version} (ONNX)"
    generator, config, states = load_ensemble(paths, run_as)
    runner = TorchModuleGenerator(generator, config.generator.input_multiple)
    how = inference_words(config.generator)
    if "published" in states[0]:
        label = f"{states[0]['published']} (eager{how})"
    elif len(paths) == 1:
        label = f"rgb2cloud ({paths[0].name}, step {states[0]['step']}{how})"
    else:
        members = "; ".join(f"{_run_name(p)} step {s['step']}" for p, s in zip(paths, states, strict=True))
        label = f"rgb2cloud (mean of {members}{how})"
    return (lambda rgb: config.depth.decode(runner.predict_raw(rgb))), label


def inference_words(g: GeneratorConfig) -> str:
    """The inference settings beyond the plain network, as a label's tail (empty when none)."""
    words = ""
    if g.flip_average:
        words += ", flip-averaged"
    if g.median_radius:
        taps = 2 * g.median_radius + 1
        words += f", colour-weighted median {taps}x{taps} taps {g.median_spacing} px apart, sigma {g.median_sigma:g}"
    if g.upsample_sigma and g.work_scale > 1:
        words += f", colour-guided upsampling, sigma {g.upsample_sigma:g}"
    return words


def _run_name(checkpoint: Path) -> str:
    """``runs/x/checkpoints/last.pt`` -> ``x/last.pt``: which run, and which of its checkpoints."""
    parent = checkpoint.parent
    run = parent.parent if parent.name == "checkpoints" else parent
    return f"{run.name}/{checkpoint.name}"


def _fmt(value: float | None) -> str:
    return "—" if value is None else f"{value:.3f}"


def markdown_table(rows: dict[str, dict]) -> str:
    """The paper's table: one row per model, the paper's columns plus PC RMSE."""
    lines = ["| model | " + " | ".join(HEADERS) + " |", "|---" * (len(HEADERS) + 1) + "|"]
    for label, m in rows.items():
        lines.append(f"| {label} | " + " | ".join(_fmt(m.get(k)) for k in COLUMNS) + " |")
    return "\n".join(lines)


def beats(ours: dict, reference: dict) -> dict[str, bool]:
    """Per metric, whether ours is strictly better than the reference."""
    return {k: (ours[k] < reference[k]) if k in LOWER_IS_BETTER else (ours[k] > reference[k]) for k in METRIC_NAMES}


def write_report(
    out_dir: Path,
    result: dict,
    per_image: list[dict],
    grid: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    *,
    split: str,
    label: str,
    depth_range: tuple[float, float],
    colour_camera: ColourCamera | None = None,
) -> str:
    """Write JSON, Markdown, the curve and the samples; return the Markdown table.

    ``colour_camera`` is recorded as ``read_at_colour_camera`` (null: pixel to pixel), so a
    card built from this file says how its numbers were read.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    table = markdown_table({label: result, "paper (TUM, Table 2)": PAPER_TUM})
    payload = {
        "split": split,
        "depth_range_m": list(depth_range),
        "averaging": "per image over its valid pixels, then the mean over images; no median scaling",
        "read_at_colour_camera": colour_camera.model_dump() if colour_camera else None,
        "metrics": result,
        "beats_paper": beats(result, PAPER_TUM),
        "per_image": per_image,
    }
    (out_dir / "metrics.json").write_text(json.dumps(payload, indent=2) + "\n")
    (out_dir / "metrics.md").write_text(
        f"# {label} on {split}\n\nValid ground truth in [{depth_range[0]}, {depth_range[1]}] m, "
        f"{result['images']} images, {result['pixels']} pixels.\n\n{table}\n"
    )
    plot_pc_curve({label: [r["pc_rmse"] for r in per_image]}, out_dir / "pc_rmse_curve.png")
    if grid:
        sample_grid(grid).save(out_dir / "samples.png")
    return table
