"""Depth PNG encoding, decoded by an independent reader (Pillow)."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from contract.encodings import depth_millimetres, encode_depth_png


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


def test_millimetres_keep_their_rule_for_every_value_either_precision_can_hold():
    """0 for no depth (NaN, infinities, zero and below), whole millimetres, and 65535 for any finite depth beyond
    65.535 m, however far: a depth whose millimetres overflow its type is still far, not missing."""
    for dtype, huge in ((np.float32, 3.4e38), (np.float64, 1e306)):
        metres = np.array([np.nan, np.inf, -np.inf, -1.0, 0.0, 1e-4, 0.0006, 1.2344, 65.535, 70.0, huge], dtype=dtype)
        expected = [0, 0, 0, 0, 0, 0, 1, 1234, 65535, 65535, 65535]
        assert depth_millimetres(metres).tolist() == expected, dtype


def test_millimetres_are_rounded_at_the_depth_s_own_precision_in_either_byte_order():
    """float64 depth is rounded from its float64 millimetres, as float32 depth from float32's: a value a
    float32 product would push over half a millimetre keeps its own rounding."""
    rng = np.random.default_rng(1)
    metres = np.concatenate([rng.uniform(0.2, 12.0, 500), np.arange(1000) / 1000 + 0.0005])
    for depth in (metres, metres.astype(np.float32)):
        expected = np.rint(depth * 1000).astype(np.uint16)
        assert np.array_equal(depth_millimetres(depth), expected)
        assert depth_millimetres(depth, ">u2").tobytes() == expected.astype(">u2").tobytes()
