"""Depth PNG encoding, decoded by an independent reader (Pillow)."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from contract.encodings import encode_depth_png


def test_depth_png_round_trips_exactly_in_millimetres():
    rng = np.random.default_rng(0)
    metres = rng.uniform(0.2, 12.0, (37, 53)).astype(np.float32)
    metres[0, :5] = [0.0, np.nan, -1.0, np.inf, 70.0]  # missing, missing, missing, missing, clipped
    with Image.open(io.BytesIO(encode_depth_png(metres))) as im:
        assert im.size == (53, 37) and im.mode.startswith("I;16")
        decoded = np.asarray(im)
    expected = np.clip(np.rint(np.nan_to_num(metres, posinf=0) * 1000), 0, 65535)
    expected[0, :4] = 0
    np.testing.assert_array_equal(decoded, expected.astype(np.uint16))
