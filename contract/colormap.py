"""Depth to colour for people. Torch-free and matplotlib-free, so the service shares it."""

from __future__ import annotations

import numpy as np


def colorize(depth: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """Depth -> HxWx3 uint8 with the 'jet' ramp (near blue, far red); missing (<= 0, NaN) is black."""
    t = np.clip((np.nan_to_num(depth) - vmin) / max(vmax - vmin, 1e-6), 0.0, 1.0)
    rgb = np.stack([np.clip(1.5 - np.abs(4 * t - c), 0.0, 1.0) for c in (3.0, 2.0, 1.0)], axis=-1)
    out = (rgb * 255 + 0.5).astype(np.uint8)
    out[~(depth > 0)] = 0
    return out
