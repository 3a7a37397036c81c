"""The lab's diagnostics: where a model's error is, measured beside the paper's metrics."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SEVEN_SCENES, run_cli

from contract.geometry import Intrinsics
from lab.diagnostics import MedianScaled, WhereFails, where_fails_line
from recordings.frames import Frame
from trainer.evaluate import evaluate_frames


def test_median_scaling_diagnostic_separates_one_wrong_distance_from_a_wrong_shape():
    """A view predicted 25% too far everywhere: raw REL 0.25, median-scaled REL 0, ratio 0.8."""
    k = Intrinsics(1, 1, 0, 0, 3, 1)
    frames = [
        Frame(np.zeros((1, 3, 3), np.uint8), np.array([[1.0, 2.0, 0.0]], np.float32), k, "near"),
        Frame(np.full((1, 3, 3), 1, np.uint8), np.array([[2.0, 4.0, 3.0]], np.float32), k, "far"),
    ]
    truth = {0: frames[0].depth, 1: frames[1].depth}

    def too_far(rgb: np.ndarray, camera: Intrinsics) -> np.ndarray:
        return np.where(truth[int(rgb[0, 0, 0])] > 0, truth[int(rgb[0, 0, 0])] * 1.25, 5.0)

    scaled = MedianScaled(0.1, 10.0)
    result, per_image, _ = evaluate_frames(too_far, frames, min_m=0.1, max_m=10.0, diagnostics=[scaled])
    assert result["rel"] == pytest.approx(0.25)
    assert result["median_scaled"]["rel"] == pytest.approx(0.0, abs=1e-6)
    assert result["median_scaled"]["delta1"] == 1.0
    assert result["median_scaled"]["ratio"] == pytest.approx({"mean": 0.8, "std": 0.0})
    assert [r["median_ratio"] for r in per_image] == pytest.approx([0.8, 0.8])  # the missing pixel is ignored
    plain, _, _ = evaluate_frames(too_far, frames, min_m=0.1, max_m=10.0)
    assert "median_scaled" not in plain and plain["rel"] == result["rel"]


def test_where_fails_splits_a_blurred_step_from_a_wrong_surface():
    """A 1 m -> 3 m step blurred over two pixels, plus one wrong pixel on the flat part, counted by hand."""
    gt = np.array([[1.0, 1, 1, 1, 1, 3, 3, 3, 3, 3, 0]], np.float32)  # the last pixel has no reading
    pred = gt.copy()
    pred[0, [4, 5]] = 2.0  # the step, blurred: ratios 2 and 1.5 both fail delta1
    pred[0, 0] = 2.0  # a wrong surface, far from the step
    pred[0, 10] = 7.0  # not counted: no ground truth
    frame = Frame(np.zeros((1, 11, 3), np.uint8), gt, Intrinsics(1, 1, 0, 0, 11, 1), "step")
    result, _, _ = evaluate_frames(lambda rgb, k: pred, [frame], min_m=0.1, max_m=10.0, diagnostics=[WhereFails()])
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
    plain, _, _ = evaluate_frames(lambda rgb, k: pred, [frame], min_m=0.1, max_m=10.0)
    assert "where_fails" not in plain


def test_where_fails_reports_no_rate_where_nothing_is_counted():
    flat = np.full((4, 4), 2.0)
    acc = WhereFails()
    acc.count(flat, flat, np.ones_like(flat, dtype=bool))
    assert acc.result() == {
        "pixels_near_steps": 0.0,
        "fail_rate_near_steps": None,
        "fail_rate_elsewhere": 0.0,
        "failures_near_steps": None,
    }
    with pytest.raises(ValueError, match="no valid"):
        WhereFails().result()


@pytest.mark.slow
def test_diagnose_prints_both_diagnostics_for_a_published_model(registry):
    stdout = run_cli(
        "diagnose",
        str(registry / "tiny" / "0.1.0"),
        "--format",
        "7scenes",
        "--root",
        str(SEVEN_SCENES),
        "--frames",
        "850-851",
        package="lab",
    ).stdout
    assert "| tiny 0.1.0 (ONNX), median-scaled |" in stdout
    assert "ground-truth/predicted median per image" in stdout and "diagnostic, where delta1 fails" in stdout


def test_the_failure_map_colours_each_pixel_by_how_delta1_judges_it():
    """Ratios 1.25 and 1/1.25 fail (too far, too near), 1.2 and 1/1.18 pass; no reading is black: counted by hand."""
    from lab.failures import PASS, TOO_FAR, TOO_NEAR, KeepViews, error_map

    sensor = np.array([[2.0, 2.0, 2.5, 2.0, 2.0, 0.0]], np.float32)
    pred = np.array([[2.0, 2.5, 2.0, 2.4, 1.7, 3.0]], np.float32)  # ratios 1, 1.25, 1/1.25, 1.2, 1/1.18, (no reading)
    valid = sensor > 0
    expected = [[list(PASS), list(TOO_FAR), list(TOO_NEAR), list(PASS), list(PASS), [0, 0, 0]]]
    assert error_map(pred, sensor, valid).tolist() == expected
    # Two of the five valid pixels fail, both on the flat part: none of the failures is at a depth step.
    frame = Frame(np.zeros((1, 6, 3), np.uint8), sensor, Intrinsics(1, 1, 0, 0, 6, 1), "flat")
    keep = KeepViews()
    _, rows, _ = evaluate_frames(lambda rgb, k: pred, [frame], min_m=0.1, max_m=10.0, diagnostics=[keep])
    assert rows[0]["delta1"] == 0.6 and rows[0]["near_steps_failed"] == 0.0 and keep.result() == {"kept": 1}


def test_the_drawn_photo_is_read_where_each_depth_pixel_sees_it():
    """A colour camera whose centre is one pixel to the right: depth pixel u shows colour pixel u + 1, by hand."""
    from contract.geometry import ColourCamera
    from lab.failures import KeepViews

    ramp = np.broadcast_to((10 * np.arange(6, dtype=np.uint8))[None, :, None], (4, 6, 3)).copy()
    depth = np.full((4, 6), 2.0, np.float32)
    depth[0, 0] = 0.0  # no reading: nothing to look up
    frame = Frame(ramp, depth, Intrinsics(10, 10, 2.5, 1.5, 6, 4), "shifted")
    keep = KeepViews(ColourCamera(fx=10, fy=10, cx=3.5, cy=1.5))
    keep.add(depth, frame, depth > 0)
    photo = keep.views["shifted"].rgb[..., 0]
    assert photo[1].tolist() == [10, 20, 30, 40, 50, 0]  # the last pixel's point is beyond the photo: black
    assert photo[0, 0] == 0 and photo[0, 1:].tolist() == [20, 30, 40, 50, 0]
    # No pixel fails, so no share of failures at depth steps: NaN, which the table prints as a dash.
    assert np.isnan(KeepViews().add(depth, frame, depth > 0)["near_steps_failed"])


def test_failures_by_depth_pool_the_views_pixels_into_near_mid_and_far():
    """Counted by hand: two views, four valid pixels near, two mid, two far; the last band keeps its upper end."""
    from lab.failures import ViewRecord, failures_by_depth

    def view(sensor: list[float], pred: list[float]) -> ViewRecord:
        return ViewRecord("v", np.zeros((1, len(sensor), 3), np.uint8), np.array([sensor]), np.array([pred]), 0.0)

    views = [
        view([1.0, 1.0, 2.0, 10.0, 0.0], [1.0, 2.0, 2.0, 5.0, 1.0]),  # near: 1 of 2 fails; mid passes; far fails
        view([0.5, 1.4, 1.5, 3.0, 20.0], [0.5, 1.0, 1.5, 3.0, 20.0]),  # near: 1 of 2 fails (1.4 / 1.0 >= 1.25)
    ]  # 1.5 and 3.0 open their bands; 20 m and 0 m have no reading in [0.1, 10]
    assert failures_by_depth(views, (0.1, 10.0)) == [
        ("0.1-1.5 m", 4 / 8, 2 / 4),
        ("1.5-3 m", 2 / 8, 0.0),
        ("3-10 m", 2 / 8, 1 / 2),
    ]
    assert [band for band, _, _ in failures_by_depth(views, (0.1, 2.0))] == ["0.1-1.5 m", "1.5-2 m"]
    assert all(np.isnan(share) and np.isnan(failing) for _, share, failing in failures_by_depth([], (0.1, 10.0)))
