"""Score a generator with the paper's metrics and write the reports people read.

Outputs in the chosen folder: ``metrics.json`` (everything, per image too),
``metrics.md`` (the paper's table with our row beside the paper's), the
Figure-8 curve ``pc_rmse_curve.png`` and ``samples.png`` (RGB | predicted | truth).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from tqdm import tqdm

from contract.card import METRIC_KEYS, ONNX_FILE, PAPER_METRICS, load_card, verify_files
from contract.engines import Engine, onnx_runner, runs
from contract.errors import UserError
from contract.geometry import ColourCamera, Intrinsics
from contract.resample import DepthRun, depth_at_photo, inference_max_pixels
from contract.runtime import RunPrecision
from recordings.frames import Frame
from recordings.registration import sample_at_colour
from trainer.checkpoint import load_graph
from trainer.config import DataSource
from trainer.data.sources import describe, open_source
from trainer.inference import EagerGenerator
from trainer.metrics import MetricAccumulator, valid_mask
from trainer.visualize import plot_pc_curve, sample_grid

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
HEADERS = ("REL", "RMSE (m)", "log10", "δ<1.25", "δ<1.25²", "δ<1.25³", "PC RMSE (m)")
LOWER_IS_BETTER = {"rel", "rmse", "log10", "pc_rmse_mean"}


class Diagnostic(Protocol):
    """Something measured beside the metrics from the same predictions (research tooling supplies these)."""

    name: str

    def add(self, pred: np.ndarray, frame: Frame, valid: np.ndarray) -> dict[str, Any]:
        """Take one image; return fields for its per-image row (may be empty)."""

    def result(self) -> dict[str, Any]:
        """The diagnostic over every image, stored under ``name`` in the evaluation's result."""


@dataclass(frozen=True)
class Predictor:
    """A model as the service runs it: a photo in, metres at the photo's size out (``contract.resample``).

    ``run`` maps HxWx3 uint8 at the model's own camera to HxW metres; ``camera`` is that camera
    (a version's card camera, a checkpoint's training camera). Calling the predictor with a
    photo and the camera that took it resamples the photo to the model's focal length first,
    so every score is of the depth the service would return for that photo.
    """

    run: DepthRun
    camera: Intrinsics
    label: str
    #: The service's ``inference_max_pixels``, read where the predictor is made.
    max_pixels: int = field(default_factory=inference_max_pixels)

    def __call__(self, rgb: np.ndarray, photo: Intrinsics) -> np.ndarray:
        return depth_at_photo(self.run, rgb, photo, self.camera, self.max_pixels)[0]


#: What ``evaluate_frames`` scores: metres at the photo's size from a photo and the camera that took it.
FramePredict = Callable[[np.ndarray, Intrinsics], np.ndarray]


def evaluate_frames(
    predict: FramePredict,
    frames: Sequence[Frame],
    *,
    min_m: float,
    max_m: float,
    samples: int = 0,
    progress: bool = False,
    colour_camera: ColourCamera | None = None,
    diagnostics: Sequence[Diagnostic] = (),
) -> tuple[dict, list[dict], list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Predict every frame at its own size (``predict(rgb, intrinsics)``) and average the per-image metrics.

    Returns (the table row, per-image rows, up to ``samples`` evenly spaced (rgb, prediction,
    ground truth) triples for a sample grid).

    ``colour_camera``: the ground truth is a depth camera's and the photo and the prediction
    the colour camera's (a model trained on registered depth): the photo is predicted as the
    colour camera's, and each ground-truth pixel is compared with the prediction at the colour
    pixel that sees the same point (``recordings.registration.sample_at_colour``), so every valid
    pixel still counts.
    Each of ``diagnostics`` sees every scored prediction; its result is added to the row.
    """
    acc = MetricAccumulator(min_m=min_m, max_m=max_m)
    per_image, grid = [], []
    keep = set(np.linspace(0, len(frames) - 1, samples).round().astype(int)) if samples else set()
    for i in tqdm(range(len(frames)), desc="evaluate", disable=not progress, unit="img"):
        frame = frames[i]
        if colour_camera is None:
            pred = predict(frame.rgb, frame.intrinsics)
        else:  # the photo is the colour camera's; the frame's intrinsics are its depth camera's
            h, w = frame.depth.shape
            pred = predict(frame.rgb, colour_camera.intrinsics(w, h))
            pred = sample_at_colour(pred, frame.depth, frame.intrinsics, colour_camera)
        row = acc.add(pred, frame.depth, frame.intrinsics, frame.name)
        if row:
            valid = valid_mask(frame.depth, min_m, max_m)
            for diagnostic in diagnostics:
                row = {**row, **diagnostic.add(pred, frame, valid)}
            per_image.append({"name": frame.name, **row})
        if i in keep:
            grid.append((frame.rgb, pred, frame.depth))
    result = acc.result()
    for diagnostic in diagnostics:
        result[diagnostic.name] = diagnostic.result()
    return result, per_image, grid


def load_predictor(
    path: Path,
    inference: dict[str, Any] | None = None,
    precision: RunPrecision = "fp32",
    engine: Engine = "onnxruntime",
) -> Predictor:
    """The predictor of a checkpoint (.pt) or a published version folder, at the model's own camera.

    A version folder is checked against its card (sha256) and, as exported, run the
    way the service runs it: ONNX Runtime, then the card's depth encoding. With
    ``inference`` (other inference settings for the same weights) a version runs
    eagerly from its TorchScript weights instead, as a checkpoint does. ``precision="int8"`` runs a version's
    int8 ONNX graph; ``engine`` runs a version's ONNX graphs on ONNX Runtime or OpenVINO (``bf16`` on
    OpenVINO, where the CPU has bf16 units), so the tables and the service can agree.
    """
    path = Path(path)
    if precision not in ("fp32", "bf16", "int8") or engine not in ("onnxruntime", "openvino"):
        raise UserError(
            f"--precision {precision!r} --engine {engine!r}: expected fp32, bf16 or int8 on onnxruntime or openvino"
        )
    if (precision != "fp32" or engine != "onnxruntime") and not (path.is_dir() and not inference):
        raise UserError(f"{path}: --precision and --engine run a published version's ONNX graphs, as published")
    if why := runs(engine, precision):
        raise UserError(f"--engine {engine} --precision {precision}: {why}")
    if path.is_dir() and not inference:
        card = load_card(path)
        verify_files(path, card)
        if precision == "int8" and card.int8 is None:
            raise UserError(f"{path}: this version has no int8 graph (publish one with export --precision int8)")
        file_name = card.int8.file if precision == "int8" and card.int8 else ONNX_FILE
        runner = onnx_runner(engine, path / file_name, card.input_multiple, 0, precision)
        how = {"fp32": "ONNX", "int8": "ONNX int8"}[precision] if engine == "onnxruntime" else f"{engine} {precision}"
        return Predictor(
            lambda rgb: card.depth_encoding.decode(runner.predict_raw(rgb)),
            card.camera,
            f"{card.name} {card.version} ({how})",
        )
    graph, weights = load_graph(path, inference)
    runner = EagerGenerator(graph, weights.config.generator.input_multiple)
    how = weights.inference.describe()
    how = f", {how}" if how else ""
    if weights.published:
        label = f"{weights.published} (eager{how})"
    else:
        label = f"rgb2cloud ({_run_name(path)}, step {weights.step}{how})"
    return Predictor(lambda rgb: weights.config.depth.decode(runner.predict_raw(rgb)), weights.camera, label)


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
        lines.append(f"| {label} | " + " | ".join(_fmt(m.get(k)) for k in METRIC_KEYS) + " |")
    return "\n".join(lines)


def beats(ours: dict, reference: dict) -> dict[str, bool]:
    """Per metric, whether ours is strictly better than the reference."""
    return {k: (ours[k] < reference[k]) if k in LOWER_IS_BETTER else (ours[k] > reference[k]) for k in PAPER_METRICS}


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
    camera_given: dict[str, float] | None = None,
) -> str:
    """Write JSON, Markdown, the curve and the samples; return the Markdown table.

    ``colour_camera`` is recorded as ``read_at_colour_camera`` (null: pixel to pixel), so a
    card built from this file says how its numbers were read; ``camera_given`` (the recording's
    camera from the command line, where its own files lacked or mistook it) as ``camera_given``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    table = markdown_table({label: result, "paper (TUM, Table 2)": PAPER_TUM})
    payload = {
        "split": split,
        "depth_range_m": list(depth_range),
        "averaging": "per image over its valid pixels, then the mean over images; no median scaling",
        "read_at_colour_camera": colour_camera.model_dump() if colour_camera else None,
        "camera_given": camera_given,
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


def score_source(
    model: Path,
    source: DataSource,
    depth_range: tuple[float, float],
    *,
    inference: dict[str, Any] | None = None,
    precision: RunPrecision = "fp32",
    engine: Engine = "onnxruntime",
    samples: int = 0,
    colour_camera: ColourCamera | None = None,
    diagnostics: Sequence[Diagnostic] = (),
) -> tuple[dict, list[dict], list[tuple[np.ndarray, np.ndarray, np.ndarray]], str]:
    """``evaluate_frames`` of a checkpoint or version on a data source, with the model's label."""
    predict = load_predictor(model, inference, precision, engine)
    result, per_image, grid = evaluate_frames(
        predict,
        open_source(source),
        min_m=depth_range[0],
        max_m=depth_range[1],
        samples=samples,
        progress=True,
        colour_camera=colour_camera,
        diagnostics=diagnostics,
    )
    return result, per_image, grid, predict.label


def evaluate_source(
    model: Path,
    source: DataSource,
    out: Path,
    inference: dict[str, Any],
    depth_range: tuple[float, float],
    samples: int,
    colour_camera: ColourCamera | None = None,
    precision: RunPrecision = "fp32",
    engine: Engine = "onnxruntime",
) -> str:
    """``rgb2cloud evaluate``: score ``model`` on ``source``, write the reports to ``out``, return the table."""
    result, per_image, grid, label = score_source(
        model,
        source,
        depth_range,
        inference=inference,
        precision=precision,
        engine=engine,
        samples=samples,
        colour_camera=colour_camera,
    )
    if colour_camera:
        label += ", read at the colour camera"
    return write_report(
        out,
        result,
        per_image,
        grid,
        split=describe(source),
        label=label,
        depth_range=depth_range,
        colour_camera=colour_camera,
        camera_given={k: v for k, v in vars(source.camera).items() if v is not None} if source.camera else None,
    )
