"""The engine rows of ``bench/serving.py --engines``: each engine and precision that runs on this CPU.

For the default model: the generator call alone at the photo's size (one engine after another), HTTP
/depth through a service started on that engine, and δ1 on the 7-Scenes test split (every 5th of frames
850-999, against the sensor) as ``evaluate --engine --precision`` scores it; then what ``auto`` chose
here and its HTTP time, in the same run. Where an engine or precision cannot run on this CPU, its row
says why, so a table from a machine without bf16 units shows that too.
"""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path

import httpx
import numpy as np

from contract.card import ONNX_FILE
from contract.engines import Engine, onnx_runner, openvino_capabilities, runs
from contract.runtime import RunPrecision
from harness.service import running_service
from harness.timing import median_ms

REPO = Path(__file__).resolve().parents[1]
SEVEN_SCENES = REPO.parent / "shared/data/7scenes-redkitchen"
#: The 7-Scenes test split as docs/quality.md scores it, every 5th frame: 30 frames.
TEST_FRAMES = ",".join(str(n) for n in range(850, 1000, 5))
ENGINES: tuple[Engine, ...] = ("onnxruntime", "openvino")
PRECISIONS: tuple[RunPrecision, ...] = ("fp32", "bf16", "int8")


def engine_rows(args: argparse.Namespace, folder: Path, photo_rgb: np.ndarray, upload: bytes) -> str:
    """The engine table for the version at ``folder``: generator ms, HTTP /depth ms and δ1 per engine and
    precision that runs here, and the reason for each that does not."""
    from contract.card import load_card

    card = load_card(folder)
    files = {"fp32": ONNX_FILE, "bf16": ONNX_FILE, "int8": card.int8.file if card.int8 else None}
    runnable, skipped = {}, {}
    for engine in ENGINES:
        for precision in PRECISIONS:
            why = runs(engine, precision) or (None if files[precision] else "the version has no int8 graph")
            if why:
                skipped[(engine, precision)] = why
            else:
                runner = onnx_runner(engine, folder / files[precision], card.input_multiple, args.threads, precision)
                runnable[(engine, precision)] = partial(runner.predict_raw, photo_rgb)
    # One row after another, not in turns: ONNX Runtime's threads spin after each call, and on a small machine
    # whatever ran next would be timed against them.
    generator = {f"{e} {p}": median_ms(call, args.repeats) for (e, p), call in runnable.items()}
    http, chosen = _http_ms(args, folder, upload, [e for e in ENGINES if any(k[0] == e for k in runnable)])
    delta1 = {key: _delta1(folder, *key) for key in runnable}
    reference = generator["onnxruntime fp32"]
    import openvino

    h, w = photo_rgb.shape[:2]
    out = (
        f"\nOpenVINO {openvino.__version__} sees this CPU offer {', '.join(openvino_capabilities())}.\n"
        f"\nEngines for {card.name} {card.version} on this CPU: the generator at {w}x{h} (one row after another), "
        f"HTTP /depth through a service on that engine, and δ1 on the 7-Scenes test split (every 5th frame of "
        f"850-999) as `evaluate --engine --precision` scores it:\n\n"
        "| engine | precision | generator ms | vs ONNX Runtime fp32 | HTTP /depth ms | δ1 |\n"
        "|---|---|---|---|---|---|\n"
    )
    for (engine, precision), ms in zip(runnable, generator.values(), strict=True):
        key = f"{engine} {precision}"
        out += (
            f"| {engine} | {precision} | {ms:.1f} | {reference / ms:.2f}x | {http.get(key, float('nan')):.1f} "
            f"| {delta1[(engine, precision)]:.4f} |\n"
        )
    for (engine, precision), why in skipped.items():
        out += f"| {engine} | {precision} | not run: {why} | | | |\n"
    auto_ms = http["auto"]
    loads = ", ".join(f"{http[f'load {e}']:.1f} s on {e}" for e in [*engines_run(http), "auto"])
    return out + (
        f"\n`RGB2CLOUD_ENGINE=auto` (the default) chose {chosen} here at load; HTTP /depth {auto_ms:.1f} ms, "
        f"{http['onnxruntime fp32'] / auto_ms:.2f}x ONNX Runtime fp32's in the same run. Loading the version "
        f"(verification, checks, measurements, warm-up) took {loads}.\n"
    )


def engines_run(http: dict) -> list[str]:
    """The engines a service ran on in ``_http_ms`` (besides auto), in order."""
    return [key.removeprefix("load ") for key in http if key.startswith("load ") and key != "load auto"]


def _http_ms(args: argparse.Namespace, folder: Path, upload: bytes, engines: list[str]) -> tuple[dict, str]:
    """Median HTTP /depth ms per engine and precision, one service at a time (an idle one's spinning threads
    would compete with the next on a small machine), then ``auto``'s, and what ``auto`` chose."""
    files = {"image": ("photo.jpg", upload)}
    registry, model = folder.parent.parent, f"{folder.parent.name}:{folder.name}"
    common = {"registry": str(registry), "threads": str(args.threads), "model": model}
    times, chosen = {}, ""
    with httpx.Client(timeout=120) as client:
        for engine in [*engines, "auto"]:
            with running_service(**common, **({} if engine == "auto" else {"engine": engine})) as service:
                listed = client.get(f"{service.url}/v1/models").json()["models"]
                serving = [v["serving"] for m in listed for v in m["versions"] if "serving" in v]
                times[f"load {engine}"] = serving[0]["load_s"]
                for precision in PRECISIONS if engine != "auto" else ("auto",):
                    post = partial(client.post, f"{service.url}/depth", files=files, params={"precision": precision})
                    probe = post()
                    if engine == "auto":
                        chosen = f"{probe.headers['x-precision']} on {probe.headers['x-engine']}"
                        times["auto"] = median_ms(post, args.repeats)
                    elif (probe.headers.get("x-precision"), probe.headers.get("x-engine")) == (precision, engine):
                        times[f"{engine} {precision}"] = median_ms(post, args.repeats)
    return times, chosen


def _delta1(folder: Path, engine: Engine, precision: RunPrecision) -> float:
    """δ1 of the version on the 7-Scenes test split, every 5th frame, run on ``engine`` at ``precision``."""
    from trainer.config import DataSource
    from trainer.evaluate import score_source

    source = DataSource(format="7scenes", root=SEVEN_SCENES, frames=TEST_FRAMES)
    result, *_ = score_source(folder, source, (0.1, 10.0), precision=precision, engine=engine)
    return float(result["delta1"])
