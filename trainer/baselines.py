"""Image-free "room average" baselines: what a model gets without looking at the photo.

* ``constant``: the median of every valid training depth, predicted everywhere.
* ``per-pixel median``: at each pixel, the median of that pixel's valid training
  depths (the constant where a pixel never had one).

Both are scored with the same metrics and pooling as the models, so a model's
numbers can be read against them: on one room, RMSE alone says little.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from contract.errors import UserError
from recordings.frames import Frame
from trainer.config import DataSource
from trainer.data.sources import describe, open_source
from trainer.evaluate import PAPER_TUM, markdown_table
from trainer.metrics import MetricAccumulator


def fit_baselines(train: Sequence[Frame]) -> dict[str, np.ndarray | float]:
    """The constant and the per-pixel median depth map from training frames (same size)."""
    first = train[0].depth
    stack = np.empty((len(train), *first.shape), dtype=np.float32)
    for i in range(len(train)):
        depth = train[i].depth
        if depth.shape != first.shape:
            raise UserError(f"{train[i].name}: {depth.shape} differs from {first.shape}; baselines need one size")
        stack[i] = np.where(depth > 0, depth, np.nan)
    constant = float(np.nanmedian(stack))
    with warnings.catch_warnings():  # pixels with no valid training depth are expected
        warnings.simplefilter("ignore", RuntimeWarning)
        per_pixel = np.nanmedian(stack, axis=0)
    per_pixel[np.isnan(per_pixel)] = constant
    return {"constant": constant, "per_pixel": per_pixel.astype(np.float32)}


def score_baselines(
    baselines: dict[str, np.ndarray | float], test: Sequence[Frame], min_m: float, max_m: float
) -> dict[str, dict]:
    """Each baseline's metrics on the test frames (same averaging as the models)."""
    accumulators = {name: MetricAccumulator(min_m=min_m, max_m=max_m) for name in baselines}
    for i in range(len(test)):
        frame = test[i]
        for name, value in baselines.items():
            pred = np.broadcast_to(np.float32(value), frame.depth.shape) if np.isscalar(value) else value
            accumulators[name].add(np.asarray(pred), frame.depth, frame.intrinsics, frame.name)
    return {name: acc.result() for name, acc in accumulators.items()}


def baselines_table(
    train_source: DataSource, test_source: DataSource, depth_range: tuple[float, float], out: Path | None = None
) -> str:
    """``rgb2cloud baselines``: fit on one split, score on another, return the table (and write JSON to ``out``)."""
    fitted = fit_baselines(open_source(train_source))
    results = score_baselines(fitted, open_source(test_source), *depth_range)
    rows = {
        f"constant {fitted['constant']:.2f} m (train median)": results["constant"],
        "per-pixel train median": results["per_pixel"],
        "paper (TUM, Table 2)": PAPER_TUM,
    }
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        payload = {
            "train": describe(train_source),
            "test": describe(test_source),
            "constant_m": fitted["constant"],
            "depth_range_m": list(depth_range),
            "metrics": results,
        }
        (out / "baselines.json").write_text(json.dumps(payload, indent=2) + "\n")
    return f"fitted on {describe(train_source)}, scored on {describe(test_source)}\n\n{markdown_table(rows)}"
