"""The decoder's ripple in served depth: 0.9.0's pixel-shuffle decoder leaves none; 0.8.1's transposed one does.

Both versions run in the real service on every 10th 7-Scenes test frame; ``lab.ripple.ripple_peaks`` gives
each period's spectral power over its neighbourhood's (about 1 without ripple; ``bench/ripple.py`` prints
the table). The bundled generators work at half the photo's resolution, so the decoder's periods of 2, 4
and 8 network pixels are 4, 8 and 16 photo pixels; 2 is checked too.
"""

from __future__ import annotations

import pytest
from conftest import SEVEN_SCENES

from harness.service import served_depths
from lab.ripple import ripple_peaks

PHOTOS = [SEVEN_SCENES / f"frame-{frame:06d}.color.jpg" for frame in range(850, 1000, 10)]
PERIODS = (2, 4, 8, 16)
#: A spectral peak this many times its neighbourhood is a ripple a point cloud shows.
RIPPLE = 3.0


@pytest.mark.slow
def test_the_new_base_serves_depth_without_the_decoders_ripple():
    new = served_depths("rgb2cloud-7scenes:0.9.0", PHOTOS)
    old = served_depths("rgb2cloud-7scenes:0.8.1", PHOTOS)
    peaks = {
        version: {axis: ripple_peaks(depths, axis, PERIODS) for axis in (0, 1)}
        for version, depths in (("0.9.0", new), ("0.8.1", old))
    }
    print(peaks)
    assert all(v < RIPPLE for axis in peaks["0.9.0"].values() for v in axis.values()), peaks["0.9.0"]
    assert max(peaks["0.8.1"][1].values()) > 3 * RIPPLE, peaks["0.8.1"]  # the measure sees the old decoder's
