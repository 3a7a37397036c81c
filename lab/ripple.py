"""The decoder's ripple: a periodic pattern in predicted depth at the periods of its 2x upsampling stages.

A transposed convolution with a 3x3 kernel and stride 2 gives alternate output pixels a different
number of kernel taps (Odena et al. 2016, "Deconvolution and checkerboard artifacts"). Three such stages
leave a pattern of periods 2, 4 and 8 pixels in depth, and so waves in every flat wall of a point
cloud. A smooth depth map's spectrum falls off evenly with frequency; the ripple is a spike above its
neighbours. ``ripple_peaks`` measures each spike as the power at that period over the median power of
the frequencies around it: about 1 where there is no ripple.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: The periods (pixels) of a three-stage 2x decoder's ripple.
PERIODS = (2, 4, 8)
#: Frequency bins on each side of a period's bin that make its neighbourhood (the bin's own
#: two neighbours left out: a window's leakage spreads a spike over them).
NEIGHBOURS = 6


def spectrum(depths: Sequence[np.ndarray], axis: int = 0) -> np.ndarray:
    """Power of log depth along ``axis`` (0: along y), summed over every line and map; Hann-windowed.

    Log depth makes a ripple of a given relative size weigh the same near and far. Missing depth (0)
    takes the line's median, which adds no period of its own.
    """
    total = None
    for depth in depths:
        lines = np.moveaxis(np.asarray(depth, dtype=np.float64), axis, -1)
        valid = lines > 0
        logs = np.log(np.where(valid, lines, 1.0))
        fill = np.zeros((*logs.shape[:-1], 1))
        some = valid.any(axis=-1)
        fill[some] = np.nanmedian(np.where(valid, logs, np.nan)[some], axis=-1, keepdims=True)
        logs = np.where(valid, logs, fill)
        logs = logs - logs.mean(axis=-1, keepdims=True)
        power = np.abs(np.fft.rfft(logs * np.hanning(logs.shape[-1]), axis=-1)) ** 2
        summed = power.reshape(-1, power.shape[-1]).sum(axis=0)
        total = summed if total is None else total + summed
    if total is None:
        raise ValueError("no depth maps")
    return total


def ripple_peaks(depths: Sequence[np.ndarray], axis: int = 0, periods: Sequence[int] = PERIODS) -> dict[int, float]:
    """Each period's power over the median of its neighbourhood's: about 1 for smooth depth, far above for ripple.

    All maps must have the same length along ``axis``, a multiple of every period.
    """
    power = spectrum(depths, axis)
    n = 2 * (len(power) - 1)
    peaks = {}
    for period in periods:
        if n % period:
            raise ValueError(f"maps of {n} pixels along axis {axis} hold no whole period of {period}")
        k = n // period
        around = [j for j in range(k - NEIGHBOURS, k + NEIGHBOURS + 1) if abs(j - k) > 1 and 0 < j < len(power)]
        peaks[period] = float(power[k] / np.median(power[around]))
    return peaks
