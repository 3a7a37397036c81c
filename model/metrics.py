"""The paper's metrics, formulas (6)-(10), and per-image point-cloud RMSE. Torch-free.

Depth metrics are pooled over every valid pixel of the whole test set (T in the
paper's formulas is the set of all test pixels), not averaged per image. A pixel
is valid when its ground truth is finite and within [min_m, max_m]; predictions
are compared in metres as they come, with no median scaling.

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

from model.geometry import Intrinsics, pixel_rays

METRIC_NAMES = ("rel", "rmse", "log10", "delta1", "delta2", "delta3")


def valid_mask(gt: np.ndarray, min_m: float, max_m: float) -> np.ndarray:
    return np.isfinite(gt) & (gt >= min_m) & (gt <= max_m)


def point_cloud_rmse(pred: np.ndarray, gt: np.ndarray, intrinsics: Intrinsics, valid: np.ndarray) -> float:
    """RMSE of the 3D distance between predicted and true points at the same pixels."""
    # Both points lie on the same pixel ray, so the distance is |d - d*| * |ray|.
    ray_length = np.linalg.norm(pixel_rays(intrinsics), axis=-1)
    distance = np.abs(pred - gt)[valid] * ray_length[valid]
    return float(np.sqrt(np.mean(distance.astype(np.float64) ** 2)))


@dataclass
class MetricAccumulator:
    """Collects pooled sums over images; ``result()`` gives the paper's table row."""

    min_m: float = 0.1
    max_m: float = 10.0
    count: int = 0
    abs_rel: float = 0.0
    sq_err: float = 0.0
    log10_err: float = 0.0
    within: list[int] = field(default_factory=lambda: [0, 0, 0])
    pc_rmse: list[float] = field(default_factory=list)
    names: list[str] = field(default_factory=list)

    def add(self, pred: np.ndarray, gt: np.ndarray, intrinsics: Intrinsics, name: str = "") -> dict[str, float]:
        """Add one image; returns that image's own metrics (for per-image reports)."""
        if pred.shape != gt.shape:
            raise ValueError(f"prediction {pred.shape} and ground truth {gt.shape} differ in size")
        valid = valid_mask(gt, self.min_m, self.max_m)
        n = int(valid.sum())
        if n == 0:
            return {}
        p = np.maximum(pred[valid].astype(np.float64), 1e-6)
        g = gt[valid].astype(np.float64)
        ratio = np.maximum(p / g, g / p)
        image = {
            "rel": float(np.mean(np.abs(p - g) / g)),
            "rmse": float(np.sqrt(np.mean((p - g) ** 2))),
            "log10": float(np.mean(np.abs(np.log10(p) - np.log10(g)))),
            "delta1": float(np.mean(ratio < 1.25)),
            "pc_rmse": point_cloud_rmse(pred, gt, intrinsics, valid),
            "pixels": n,
        }
        self.count += n
        self.abs_rel += float(np.sum(np.abs(p - g) / g))
        self.sq_err += float(np.sum((p - g) ** 2))
        self.log10_err += float(np.sum(np.abs(np.log10(p) - np.log10(g))))
        for k in range(3):
            self.within[k] += int(np.sum(ratio < 1.25 ** (k + 1)))
        self.pc_rmse.append(image["pc_rmse"])
        self.names.append(name)
        return image

    def result(self) -> dict[str, float]:
        if self.count == 0:
            raise ValueError("no valid ground-truth pixels were seen")
        return {
            "rel": self.abs_rel / self.count,
            "rmse": float(np.sqrt(self.sq_err / self.count)),
            "log10": self.log10_err / self.count,
            "delta1": self.within[0] / self.count,
            "delta2": self.within[1] / self.count,
            "delta3": self.within[2] / self.count,
            "pc_rmse_mean": float(np.mean(self.pc_rmse)),
            "images": len(self.pc_rmse),
            "pixels": self.count,
        }


def pc_rmse_curve(pc_rmse: list[float], thresholds: np.ndarray) -> np.ndarray:
    """The paper's Figure 8: fraction of images whose point-cloud RMSE is below r."""
    values = np.asarray(pc_rmse)
    return np.array([(values < r).mean() for r in thresholds])
