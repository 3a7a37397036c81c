"""Pictures for people: colour-mapped depth, sample grids, the Figure-8 curve."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: we only ever write files
import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

from model.metrics import pc_rmse_curve


def colorize(depth: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """Depth -> HxWx3 uint8 with the 'turbo' map; missing depth (<= 0) is black."""
    t = np.clip((depth - vmin) / max(vmax - vmin, 1e-6), 0.0, 1.0)
    rgb = (matplotlib.colormaps["turbo"](t)[..., :3] * 255).astype(np.uint8)
    rgb[~(depth > 0)] = 0
    return rgb


def sample_grid(rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> Image.Image:
    """One row per sample: RGB | predicted | ground truth, depths on one shared scale per row."""
    tiles = []
    for rgb, pred, gt in rows:
        valid = gt[gt > 0]
        vmin, vmax = np.percentile(valid, [2, 98]) if valid.size else (pred.min(), pred.max())
        tiles.append(np.concatenate([rgb, colorize(pred, vmin, vmax), colorize(gt, vmin, vmax)], axis=1))
    width = max(t.shape[1] for t in tiles)
    padded = [np.pad(t, ((0, 0), (0, width - t.shape[1]), (0, 0))) for t in tiles]
    return Image.fromarray(np.concatenate(padded, axis=0))


def plot_pc_curve(curves: dict[str, list[float]], path: Path, r_max: float = 1.0) -> None:
    """Fraction of images with point-cloud RMSE < r, one line per model (Figure 8)."""
    r = np.linspace(0.0, r_max, 201)
    fig, ax = plt.subplots(figsize=(5.5, 4), dpi=120)
    for label, values in curves.items():
        ax.plot(r, pc_rmse_curve(values, r), label=label)
    ax.set_xlabel("point-cloud RMSE threshold r (m)")
    ax.set_ylabel("fraction of test images with RMSE < r")
    ax.set_xlim(0, r_max)
    ax.set_ylim(0, 1.01)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
