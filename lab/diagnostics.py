"""Diagnostics beside the paper's metrics, for choosing what to try next: where the error is.

A pixel fails delta1 when max(d / d*, d* / d) >= 1.25. Failures have two different
causes that call for different changes:

- a whole view at the wrong distance fails smooth surfaces everywhere. ``MedianScaled``
  measures it: each prediction scaled by its own ground-truth/predicted median ratio
  (median scaling, never the headline protocol), and that ratio's spread over the images;
- a blurred or misplaced depth step fails only the few pixels beside each step, where
  no per-view scale can help. ``WhereFails`` counts them.

For ``WhereFails`` So each valid pixel is labelled *near a step*
when, within ``STEP_RADIUS`` pixels, the ground truth's largest valid depth is more
than ``STEP_RATIO`` times its smallest (the same 1.25 as delta1: a prediction
half-way across such a step fails). The counts are pooled over all pixels of
all images, because the question is which pixels, not which images.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

from contract.errors import UserError
from contract.geometry import ColourCamera
from recordings.frames import Frame
from trainer.config import DataSource
from trainer.data.sources import describe
from trainer.evaluate import markdown_table, score_source
from trainer.metrics import MetricAccumulator

STEP_RATIO = 1.25
STEP_RADIUS = 3


def median_ratio(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> float:
    """Ground-truth median over predicted median at the valid pixels: the scale median scaling applies."""
    return float(np.median(gt[valid]) / max(float(np.median(pred[valid])), 1e-6))


class MedianScaled:
    """The metrics after scaling each prediction by its ``median_ratio``, and that ratio's mean and spread.

    Far from 1 on every image means the error is mostly one wrong distance per view
    rather than a wrong shape.
    """

    name = "median_scaled"

    def __init__(self, min_m: float, max_m: float):
        self.scaled = MetricAccumulator(min_m=min_m, max_m=max_m)
        self.ratios: list[float] = []

    def add(self, pred: np.ndarray, frame: Frame, valid: np.ndarray) -> dict[str, float]:
        ratio = median_ratio(pred, frame.depth, valid)
        self.ratios.append(ratio)
        self.scaled.add(pred * ratio, frame.depth, frame.intrinsics, frame.name)
        return {"median_ratio": ratio}

    def result(self) -> dict:
        return {
            **self.scaled.result(),
            "ratio": {"mean": float(np.mean(self.ratios)), "std": float(np.std(self.ratios))},
        }


def near_depth_steps(gt: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Valid pixels within ``STEP_RADIUS`` of a ground-truth depth step steeper than ``STEP_RATIO``."""
    size = 2 * STEP_RADIUS + 1
    highest = maximum_filter(np.where(valid, gt, 0.0), size=size, mode="nearest")
    lowest = minimum_filter(np.where(valid, gt, np.inf), size=size, mode="nearest")
    return valid & (highest > STEP_RATIO * lowest)


#: δ1's threshold: a pixel fails where prediction and sensor differ by this factor or more.
DELTA1_RATIO = 1.25


def delta1_error(pred: np.ndarray, sensor: np.ndarray) -> np.ndarray:
    """+1 where the prediction is DELTA1_RATIO times the sensor's depth or more, -1 where that much nearer, else 0."""
    p = np.maximum(np.nan_to_num(pred.astype(np.float64)), 1e-6)
    s = np.maximum(sensor.astype(np.float64), 1e-6)
    return np.where(p / s >= DELTA1_RATIO, 1, np.where(s / p >= DELTA1_RATIO, -1, 0))


@dataclass
class WhereFails:
    """Pooled delta1 failures, split by whether the pixel lies near a depth step."""

    name = "where_fails"
    valid: int = 0
    near: int = 0
    failed: int = 0
    failed_near: int = 0

    def add(self, pred: np.ndarray, frame: Frame, valid: np.ndarray) -> dict:
        self.count(pred, frame.depth, valid)
        return {}

    def count(self, pred: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> None:
        fails = valid & (delta1_error(pred, gt) != 0)
        near = near_depth_steps(gt, valid)
        self.valid += int(valid.sum())
        self.near += int(near.sum())
        self.failed += int(fails.sum())
        self.failed_near += int((fails & near).sum())

    def result(self) -> dict[str, float | None]:
        """Shares of pixels; a rate is None where it has no pixel to count."""
        if not self.valid:
            raise UserError("no valid ground-truth pixels were seen")
        smooth = self.valid - self.near
        return {
            "pixels_near_steps": self.near / self.valid,
            "fail_rate_near_steps": self.failed_near / self.near if self.near else None,
            "fail_rate_elsewhere": (self.failed - self.failed_near) / smooth if smooth else None,
            "failures_near_steps": self.failed_near / self.failed if self.failed else None,
        }


def where_fails_line(shares: dict[str, float | None]) -> str:
    """One sentence for the console: how many pixels sit near steps and how they fare."""

    def pct(value: float | None) -> str:
        return "n/a" if value is None else f"{100 * value:.1f}%"

    return (
        f"diagnostic, where delta1 fails: {pct(shares['pixels_near_steps'])} of valid pixels lie within "
        f"{STEP_RADIUS} px of a depth step of over {STEP_RATIO}x; they fail at {pct(shares['fail_rate_near_steps'])}, "
        f"the rest at {pct(shares['fail_rate_elsewhere'])}; {pct(shares['failures_near_steps'])} of all failures "
        "are near steps"
    )


def diagnose_source(
    model: Path, source: DataSource, depth_range: tuple[float, float], colour_camera: ColourCamera | None
) -> str:
    """``rgb2cloud-lab diagnose``: the paper's row, the median-scaled row and where delta1 fails, as text."""
    diagnostics = [MedianScaled(*depth_range), WhereFails()]
    result, _, _, label = score_source(model, source, depth_range, colour_camera=colour_camera, diagnostics=diagnostics)
    scaled = result["median_scaled"]
    ratio = scaled["ratio"]
    return "\n".join(
        [
            f"{label} on {describe(source)}",
            "",
            markdown_table({label: result, f"{label}, median-scaled": scaled}),
            "",
            f"ground-truth/predicted median per image {ratio['mean']:.3f} +- {ratio['std']:.3f}",
            where_fails_line(result["where_fails"]),
        ]
    )
