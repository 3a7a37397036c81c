"""The paper's metrics against values worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from contract.geometry import Intrinsics, point_cloud, xyz
from trainer.metrics import MetricAccumulator, pc_rmse_curve, point_cloud_rmse


def test_formulas_6_to_10_hand_computed():
    k = Intrinsics(1, 1, 0, 0, 5, 1)
    pred = np.array([[1.0, 2.0, 4.0, 3.0, 3.0]])
    gt = np.array([[2.0, 2.0, 2.0, 0.0, 50.0]])  # 0 = missing, 50 m is beyond the range
    acc = MetricAccumulator(min_m=0.1, max_m=10.0)
    acc.add(pred, gt, k)
    m = acc.result()
    assert m["rel"] == pytest.approx((0.5 + 0 + 1) / 3)
    assert m["rmse"] == pytest.approx(math.sqrt((1 + 0 + 4) / 3))
    assert m["log10"] == pytest.approx(2 * math.log10(2) / 3)
    # ratios 2, 1, 2: only the exact pixel is within 1.25, 1.5625 and 1.953.
    assert (m["delta1"], m["delta2"], m["delta3"]) == pytest.approx((1 / 3, 1 / 3, 1 / 3))
    assert m["pixels"] == 3


def test_averaged_per_image_not_pooled_over_pixels():
    k1, k2 = Intrinsics(1, 1, 0, 0, 1, 1), Intrinsics(1, 1, 0, 0, 3, 1)
    acc = MetricAccumulator()
    acc.add(np.array([[2.0]]), np.array([[1.0]]), k1)  # REL 1
    acc.add(np.array([[1.0, 1.0, 1.0]]), np.array([[1.0, 1.0, 1.0]]), k2)  # REL 0
    assert acc.result()["rel"] == pytest.approx((1 + 0) / 2)  # not 1 / 4 pixels
    assert acc.result()["images"] == 2 and acc.result()["pixels"] == 4


def test_point_cloud_rmse_is_3d_distance_at_the_same_pixels():
    k = Intrinsics(1.0, 1.0, 0.0, 0.0, 2, 1)
    pred, gt = np.array([[3.0, 3.0]]), np.array([[2.0, 1.0]])
    valid = np.ones_like(gt, dtype=bool)
    # pixel (0,0): ray (0,0,1), distance 1; pixel (1,0): ray (1,0,1), distance 2 * sqrt(2)
    assert point_cloud_rmse(pred, gt, k, valid) == pytest.approx(math.sqrt((1 + 8) / 2))
    colours = np.zeros((1, 2, 3), np.uint8)
    explicit = np.linalg.norm(xyz(point_cloud(pred, colours, k)) - xyz(point_cloud(gt, colours, k)), axis=-1)
    assert point_cloud_rmse(pred, gt, k, valid) == pytest.approx(np.sqrt(np.mean(explicit**2)))


def test_figure_8_curve():
    np.testing.assert_allclose(pc_rmse_curve([0.1, 0.3, 0.5, 0.7], np.array([0.0, 0.2, 0.6, 1.0])), [0, 0.25, 0.75, 1])
