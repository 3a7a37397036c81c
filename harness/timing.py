"""Median wall-clock times for the benchmarks: one call alone, or several taking turns."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    """Median ms of ``fn`` over ``repeats`` runs after one warm-up run."""
    return interleaved_ms({"": fn}, repeats)[""]


def interleaved_ms(calls: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median ms of each call, the calls taking turns, so that load on a shared machine hits them alike."""
    times: dict[str, list[float]] = {label: [] for label in calls}
    for call in calls.values():
        call()  # warm
    for _ in range(repeats):
        for label, call in calls.items():
            start = time.perf_counter()
            call()
            times[label].append(time.perf_counter() - start)
    return {label: statistics.median(t) * 1000 for label, t in times.items()}
