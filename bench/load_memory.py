"""The memory a replica needs for one version: resident and peak while it loads (every engine and precision
built, checked at the sample's size and at twice it, and timed), then after a photo at the largest size the
service runs, on every precision it serves. For sizing a replica's limit (``deploy/compose.yaml`` gives 1 GB).

    python bench/load_memory.py weights/rgb2cloud-7scenes/0.9.0 [--engine auto]

Run it in a fresh process: the peak is the process's own (``ru_maxrss``).
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np

from app.loading import load_version
from app.settings import Settings
from contract.resample import INFERENCE_MAX_PIXELS
from trainer.machine import cpu_description


def resident_mb() -> float:
    """This process's resident memory now (``VmRSS``), in MB."""
    status = Path("/proc/self/status").read_text()
    return int(status.split("VmRSS:")[1].split()[0]) / 1024


def peak_mb() -> float:
    """The most this process has been resident so far, in MB (Linux gives ``ru_maxrss`` in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("version", type=Path, help="a published version folder")
    parser.add_argument("--engine", default="auto", help="the service's RGB2CLOUD_ENGINE (default auto)")
    parser.add_argument("--threads", type=int, default=2, help="the service's RGB2CLOUD_THREADS (default 2)")
    args = parser.parse_args()

    settings = Settings(registry=args.version.parent.parent, engine=args.engine, threads=args.threads)
    rows = [("before the load", resident_mb(), peak_mb())]
    began = time.perf_counter()
    model = load_version(args.version, settings)
    loaded_s = time.perf_counter() - began
    rows.append((f"loaded in {loaded_s:.1f} s", resident_mb(), peak_mb()))
    width = int((INFERENCE_MAX_PIXELS * 4 / 3) ** 0.5)
    largest = np.random.default_rng(0).integers(0, 256, (width * 3 // 4, width, 3), dtype=np.uint8)
    for precision in model.generators:
        model.predict_depth(largest, precision)
        rows.append((f"after a {width}x{width * 3 // 4} photo on {precision}", resident_mb(), peak_mb()))

    served = ", ".join(f"{p} on {e}" for p, e in model.engines.items())
    print(f"Machine: {cpu_description()}; {args.threads} threads, engine {args.engine}.")
    print(f"{model.card.name} {model.card.version}: serves {served}.\n")
    print("| moment | resident MB | peak MB |\n|---|---|---|")
    for moment, resident, peak in rows:
        print(f"| {moment} | {resident:.0f} | {peak:.0f} |")


if __name__ == "__main__":
    main()
