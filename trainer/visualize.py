"""Pictures for people: sample grids and the Figure-8 curve (colours from ``contract.colormap``)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: we only ever write files
import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

from contract.colormap import colorize
from trainer.metrics import pc_rmse_curve


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
    # Below the axes, one entry per line: report labels are sentences, which squeeze the plot inside it.
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.15), fontsize="small", frameon=False)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
