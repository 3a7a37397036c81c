"""Which engine serves each precision of a version: every candidate that passed its check is timed on the check
photo, and ONNX Runtime, the reference, is kept unless another is faster beyond the timing's own noise, so two
near-equal engines do not swap from one load to the next (``app.loading.load_version`` asks)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from contract.engines import Engine
from contract.runtime import ExportedGenerator

#: Timed runs of each candidate on the check photo, after one warm-up run.
TIMED_RUNS = 5
#: How much faster than ONNX Runtime (the reference) another engine's median must be to be served instead, on
#: top of every one of its runs being faster than every one of ONNX Runtime's.
MARGIN = 0.05


@dataclass(frozen=True)
class Timing:
    """One candidate's timed runs on the check photo, in ms: the median is its time, the range its noise."""

    runs: tuple[float, ...]

    @property
    def median(self) -> float:
        return float(np.median(self.runs))

    def __str__(self) -> str:
        return f"{self.median:.1f} ms ({min(self.runs):.1f}-{max(self.runs):.1f})"


def timings(
    runners: dict[Engine, ExportedGenerator], photo: np.ndarray, clock: Callable[[], float] = time.perf_counter
) -> tuple[dict[Engine, Timing], dict[Engine, str]]:
    """Each runner's ``TIMED_RUNS`` runs on ``photo`` after a warm-up, one runner after another; and why each
    that raised did.

    Not in turns: ONNX Runtime's threads spin for a while after each call, and on a small machine the
    call that follows one, whichever engine, would be timed against them.
    """
    times: dict[Engine, Timing] = {}
    failed: dict[Engine, str] = {}
    for engine, runner in runners.items():
        runs_ms = []
        try:
            runner.predict_raw(photo)
            for _ in range(TIMED_RUNS):
                began = clock()
                runner.predict_raw(photo)
                runs_ms.append((clock() - began) * 1000)
        except Exception as e:
            failed[engine] = f"its run on {engine} failed while timed: {e}"
            continue
        times[engine] = Timing(tuple(runs_ms))
    return times, failed


def fastest(times: dict[Engine, Timing]) -> tuple[Engine, str]:
    """The engine a precision is served on, and why in the words the load log and ``/v1/models`` give.

    ONNX Runtime, the reference, unless another engine ran faster in every timed run than ONNX Runtime did in
    any, with a median ``MARGIN`` lower: a gap beyond the timing's own noise, so the choice between near
    equals does not flip from one load to the next. Without ONNX Runtime, the lowest median.
    """
    best = min(times, key=lambda engine: times[engine].median)
    others = ", ".join(f"{engine} {timing}" for engine, timing in times.items() if engine != best)
    if len(times) == 1:
        return best, f"{best} {times[best]}, the only engine timed"
    if "onnxruntime" not in times:
        return best, f"{best} {times[best]}, the fastest (against {others})"
    reference = times["onnxruntime"]
    if best == "onnxruntime":
        return best, f"onnxruntime {reference}, the fastest (against {others})"
    challenger = times[best]
    gain = 1 - challenger.median / reference.median
    if max(challenger.runs) < min(reference.runs) and gain >= MARGIN:
        return best, f"{best} {challenger}, {gain:.0%} faster than onnxruntime {reference} in every run"
    return "onnxruntime", (
        f"onnxruntime {reference}: {best} {challenger} is not faster in every run by {MARGIN:.0%} or more"
    )
