"""Image-free "room average" baselines: what a model gets without looking at the photo.

* ``constant``: the median of every valid training depth, predicted everywhere.
* ``per-pixel median``: at each pixel, the median of that pixel's valid training
  depths (the constant where a pixel never had one).

Both are scored with the same metrics and pooling as the models, so a model's
numbers can be read against them: on one room, RMSE alone says little.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from model.data.frames import Frame
from model.metrics import MetricAccumulator


def fit_baselines(train: Sequence[Frame]) -> dict[str, np.ndarray | float]:
    """The constant and the per-pixel median depth map from training frames (same size)."""
    first = train[0].depth
    stack = np.empty((len(train), *first.shape), dtype=np.float32)
    for i in range(len(train)):
        depth = train[i].depth
        if depth.shape != first.shape:
            raise ValueError(f"{train[i].name}: {depth.shape} differs from {first.shape}; baselines need one size")
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
