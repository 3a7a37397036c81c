"""The image-free baselines, fitted and scored on frames built here."""

from __future__ import annotations

import numpy as np
import pytest

from contract.geometry import Intrinsics
from recordings.frames import Frame
from trainer.baselines import fit_baselines, score_baselines

K = Intrinsics(1, 1, 0, 0, 2, 1)


def _frame(depth) -> Frame:
    depth = np.array([depth], dtype=np.float32)
    return Frame(np.zeros((1, 2, 3), np.uint8), depth, K, "f")


def test_constant_and_per_pixel_medians():
    train = [_frame([1.0, 0.0]), _frame([2.0, 0.0]), _frame([3.0, 4.0])]
    fitted = fit_baselines(train)
    assert fitted["constant"] == pytest.approx(2.5)  # median of 1, 2, 3, 4 (holes ignored)
    np.testing.assert_allclose(fitted["per_pixel"], [[2.0, 4.0]])
    scores = score_baselines(fitted, [_frame([2.0, 4.0])], 0.1, 10.0)
    assert scores["per_pixel"]["rel"] == 0.0 and scores["per_pixel"]["delta1"] == 1.0
    assert scores["constant"]["rel"] == pytest.approx((0.5 / 2 + 1.5 / 4) / 2)
