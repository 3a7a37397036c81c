"""The paper's metrics against values worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from model.geometry import Intrinsics, point_cloud, xyz
from model.metrics import MetricAccumulator, pc_rmse_curve, point_cloud_rmse


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


def test_median_scaling_diagnostic_separates_one_wrong_distance_from_a_wrong_shape():
    """A view predicted 25% too far everywhere: raw REL 0.25, median-scaled REL 0, ratio 0.8."""
    from model.data.frames import Frame
    from model.evaluate import evaluate_frames

    k = Intrinsics(1, 1, 0, 0, 3, 1)
    frames = [
        Frame(np.zeros((1, 3, 3), np.uint8), np.array([[1.0, 2.0, 0.0]], np.float32), k, "near"),
        Frame(np.full((1, 3, 3), 1, np.uint8), np.array([[2.0, 4.0, 3.0]], np.float32), k, "far"),
    ]
    truth = {0: frames[0].depth, 1: frames[1].depth}

    def too_far(rgb: np.ndarray) -> np.ndarray:
        return np.where(truth[int(rgb[0, 0, 0])] > 0, truth[int(rgb[0, 0, 0])] * 1.25, 5.0)

    result, per_image, _ = evaluate_frames(too_far, frames, min_m=0.1, max_m=10.0, median_scaled=True)
    assert result["rel"] == pytest.approx(0.25)
    assert result["median_scaled"]["rel"] == pytest.approx(0.0, abs=1e-6)
    assert result["median_scaled"]["delta1"] == 1.0
    assert result["median_ratio"] == pytest.approx({"mean": 0.8, "std": 0.0})
    assert [r["median_ratio"] for r in per_image] == pytest.approx([0.8, 0.8])  # the missing pixel is ignored
    plain, _, _ = evaluate_frames(too_far, frames, min_m=0.1, max_m=10.0)
    assert "median_scaled" not in plain and plain["rel"] == result["rel"]


def test_where_fails_splits_a_blurred_step_from_a_wrong_surface():
    """A 1 m -> 3 m step blurred over two pixels, plus one wrong pixel on the flat part, counted by hand."""
    from model.data.frames import Frame
    from model.evaluate import evaluate_frames
    from model.failures import where_fails_line

    gt = np.array([[1.0, 1, 1, 1, 1, 3, 3, 3, 3, 3, 0]], np.float32)  # the last pixel has no reading
    pred = gt.copy()
    pred[0, [4, 5]] = 2.0  # the step, blurred: ratios 2 and 1.5 both fail delta1
    pred[0, 0] = 2.0  # a wrong surface, far from the step
    pred[0, 10] = 7.0  # not counted: no ground truth
    frame = Frame(np.zeros((1, 11, 3), np.uint8), gt, Intrinsics(1, 1, 0, 0, 11, 1), "step")
    result, _, _ = evaluate_frames(lambda rgb: pred, [frame], min_m=0.1, max_m=10.0, where_fails=True)
    # within 3 px of both sides of the step: pixels 2-7, 6 of the 10 valid ones
    assert result["where_fails"] == pytest.approx(
        {
            "pixels_near_steps": 0.6,
            "fail_rate_near_steps": 2 / 6,
            "fail_rate_elsewhere": 1 / 4,
            "failures_near_steps": 2 / 3,
        }
    )
    assert result["delta1"] == pytest.approx(0.7)
    assert "60.0% of valid pixels" in where_fails_line(result["where_fails"])
    plain, _, _ = evaluate_frames(lambda rgb: pred, [frame], min_m=0.1, max_m=10.0)
    assert "where_fails" not in plain


def test_where_fails_reports_no_rate_where_nothing_is_counted():
    from model.failures import FailureAccumulator

    flat = np.full((4, 4), 2.0)
    acc = FailureAccumulator()
    acc.add(flat, flat, np.ones_like(flat, dtype=bool))
    assert acc.result() == {
        "pixels_near_steps": 0.0,
        "fail_rate_near_steps": None,
        "fail_rate_elsewhere": 0.0,
        "failures_near_steps": None,
    }
    with pytest.raises(ValueError, match="no valid"):
        FailureAccumulator().result()
