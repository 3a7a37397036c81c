"""The paper's metrics, formulas (6)-(10), and per-image point-cloud RMSE. Torch-free.

Each metric is computed over one image's valid pixels and then averaged over the
images, the convention of Eigen et al. and most depth papers (it reproduces the
team's published room-average baselines exactly; pooling every pixel of the set
instead moves them in the third decimal). A pixel is valid when its ground truth
is finite and within [min_m, max_m]; predictions are compared in metres as they
come, with no median scaling.

    REL    = mean |d - d*| / d*
    RMSE   = sqrt(mean (d - d*)^2)
    log10  = mean |log10 d - log10 d*|
    delta_k = fraction with max(d / d*, d* / d) < 1.25^k,  k = 1, 2, 3

Point-cloud RMSE (per image): both depths are back-projected with formula (5)
at the same valid pixels, and the RMSE of the 3D distances is taken.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from contract.card import PAPER_METRICS
from contract.errors import UserError
from contract.geometry import Intrinsics, ray_factors


def valid_mask(gt: np.ndarray, min_m: float, max_m: float) -> np.ndarray:
    return np.isfinite(gt) & (gt >= min_m) & (gt <= max_m)


def point_cloud_rmse(pred: np.ndarray, gt: np.ndarray, intrinsics: Intrinsics, valid: np.ndarray) -> float:
    """RMSE of the 3D distance between predicted and true points at the same pixels."""
    # Both points lie on the same pixel ray, so the distance is |d - d*| * |ray|.
    x_factor, y_factor = ray_factors(intrinsics)
    ray_length = np.sqrt(x_factor[None, :] ** 2 + y_factor[:, None] ** 2 + 1.0)
    distance = np.abs(pred - gt)[valid] * ray_length[valid]
    return float(np.sqrt(np.mean(distance.astype(np.float64) ** 2)))


@dataclass
class MetricAccumulator:
    """Collects per-image metrics; ``result()`` averages them into the paper's table row."""

    min_m: float = 0.1
    max_m: float = 10.0
    rows: list[dict[str, float]] = field(default_factory=list)

    def add(self, pred: np.ndarray, gt: np.ndarray, intrinsics: Intrinsics, name: str = "") -> dict[str, float]:
        """Add one image; returns its own metrics ({} if it has no valid pixel)."""
        if pred.shape != gt.shape:
            raise ValueError(f"prediction {pred.shape} and ground truth {gt.shape} differ in size")
        valid = valid_mask(gt, self.min_m, self.max_m)
        if not valid.any():
            return {}
        p = np.maximum(pred[valid].astype(np.float64), 1e-6)
        g = gt[valid].astype(np.float64)
        ratio = np.maximum(p / g, g / p)
        row = {
            "rel": float(np.mean(np.abs(p - g) / g)),
            "rmse": float(np.sqrt(np.mean((p - g) ** 2))),
            "log10": float(np.mean(np.abs(np.log10(p) - np.log10(g)))),
            **{f"delta{k}": float(np.mean(ratio < 1.25**k)) for k in (1, 2, 3)},
            "pc_rmse": point_cloud_rmse(pred, gt, intrinsics, valid),
            "pixels": int(valid.sum()),
        }
        self.rows.append(row)
        return row

    @property
    def pc_rmse(self) -> list[float]:
        return [r["pc_rmse"] for r in self.rows]

    def result(self) -> dict[str, float]:
        if not self.rows:
            raise UserError("no valid ground-truth pixels were seen")
        mean = {k: float(np.mean([r[k] for r in self.rows])) for k in PAPER_METRICS}
        return {
            **mean,
            "pc_rmse_mean": float(np.mean(self.pc_rmse)),
            "images": len(self.rows),
            "pixels": int(sum(r["pixels"] for r in self.rows)),
        }


def pc_rmse_curve(pc_rmse: list[float], thresholds: np.ndarray) -> np.ndarray:
    """The paper's Figure 8: fraction of images whose point-cloud RMSE is below r."""
    values = np.asarray(pc_rmse)
    return np.array([(values < r).mean() for r in thresholds])
