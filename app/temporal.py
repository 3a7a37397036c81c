"""A stream's temporal filter: each pixel's depth blended with the last frame's where the two agree.

Edge-aware in time as the RealSense SDK's temporal filter is: where a pixel's new depth is within
``delta`` (relative) of the last filtered depth at that pixel, the two are blended by ``alpha``; where it
is not (an edge moved across the pixel, something entered the view) the new depth is taken as it is, so
motion is never smeared across a depth step. A live stream has no camera poses, so the blend is at the
same pixel, not the same surface point: docs/quality.md measures what that buys and costs on a moving
camera, and why the filter is an option and not the default.
"""

from __future__ import annotations

import numpy as np

#: The weight of the new frame, and the relative difference beyond which a pixel starts afresh.
ALPHA = 0.4
DELTA = 0.05


class TemporalFilter:
    """The filtered depth so far; ``apply`` each frame of one stream in order."""

    def __init__(self, alpha: float = ALPHA, delta: float = DELTA):
        self.alpha, self.delta = alpha, delta
        self._last: np.ndarray | None = None

    def apply(self, depth: np.ndarray) -> np.ndarray:
        """The frame's depth (metres, 0 or NaN = none), filtered with what came before it."""
        last = self._last
        if last is None or last.shape != depth.shape:
            filtered = depth.astype(np.float32, copy=True)
        else:
            with np.errstate(invalid="ignore"):
                agree = (last > 0) & (depth > 0) & (np.abs(depth - last) <= self.delta * last)
            filtered = np.where(agree, self.alpha * depth + (1 - self.alpha) * last, depth).astype(np.float32)
        self._last = filtered
        return filtered
