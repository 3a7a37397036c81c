"""Where delta1 fails: at the ground truth's depth steps or on smooth surfaces.

A diagnostic beside the paper's metrics, for choosing what to try next. A pixel
fails delta1 when max(d / d*, d* / d) >= 1.25. Failures have two different
causes that call for different changes: a whole view at the wrong distance
(which ``median_ratio`` measures) fails smooth surfaces everywhere, while a
blurred or misplaced depth step fails only the few pixels beside each step,
where no per-view scale can help. So each valid pixel is labelled *near a step*
when, within ``STEP_RADIUS`` pixels, the ground truth's largest valid depth is more
than ``STEP_RATIO`` times its smallest (the same 1.25 as delta1: a prediction
half-way across such a step fails). The counts are pooled over all pixels of
all images, because the question is which pixels, not which images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

STEP_RATIO = 1.25
STEP_RADIUS = 3


def near_depth_steps(gt: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Valid pixels within ``STEP_RADIUS`` of a ground-truth depth step steeper than ``STEP_RATIO``."""
    size = 2 * STEP_RADIUS + 1
    highest = maximum_filter(np.where(valid, gt, 0.0), size=size, mode="nearest")
    lowest = minimum_filter(np.where(valid, gt, np.inf), size=size, mode="nearest")
    return valid & (highest > STEP_RATIO * lowest)


@dataclass
class FailureAccumulator:
    """Pooled delta1 failures, split by whether the pixel lies near a depth step."""

    valid: int = 0
    near: int = 0
    failed: int = 0
    failed_near: int = 0

    def add(self, pred: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> None:
        p = np.maximum(pred.astype(np.float64), 1e-6)
        g = np.where(valid, gt, 1.0).astype(np.float64)
        fails = valid & (np.maximum(p / g, g / p) >= 1.25)
        near = near_depth_steps(gt, valid)
        self.valid += int(valid.sum())
        self.near += int(near.sum())
        self.failed += int(fails.sum())
        self.failed_near += int((fails & near).sum())

    def result(self) -> dict[str, float | None]:
        """Shares of pixels; a rate is None where it has no pixel to count."""
        if not self.valid:
            raise ValueError("no valid ground-truth pixels were seen")
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
