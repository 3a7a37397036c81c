"""Where a stream frame's time goes (``python bench/stream.py --stages``): each stage on the client and on the
service, per frame and as medians, for each model and depth encoding, one lockstep stream at a time.

The client's stages are its own wall clock around each call: sending the JPEG, waiting for the answer's JSON
header, reading the payloads it lists, and decoding the depth into metres (Pillow for ``png16``, NumPy for
``raw16``). The service's come from each header (``stages_ms``, and ``queued_ms``, the wait in the stream's
mailbox). "Transport and event loop" is the rest of the wait for the header: the frame's bytes crossing the
socket, the service's read and hand-over to the inference pool, and the header's way back.
"""

from __future__ import annotations

import io
import json
import statistics
import time
from collections.abc import Callable

import numpy as np
from PIL import Image

from clients.stream import open_stream, raw_depth

#: The client's stages, in the order a frame meets them.
CLIENT = ("send", "wait for the header", "read the payloads", "decode the depth")
#: The service's stages, in the order it runs them (a stream's ``stages_ms``).
SERVICE = ("queued", "decode", "resample", "inference", "resample_back", "encode")
TRANSPORT = "transport and event loop"
#: Stages a stream runs only when asked (``smooth``), and any the service adds after this table was written.
OTHER = "other stages"


def depth_metres(entry: dict, body: bytes) -> np.ndarray:
    """The depth payload in metres, as a client would use it."""
    if entry["encoding"] == "png16":
        return np.asarray(Image.open(io.BytesIO(body)), dtype=np.float32) / 1000.0
    return raw_depth(entry, body)


def frame_stages(url: str, frames: list[bytes], seconds: float, **options) -> tuple[list[dict[str, float]], str]:
    """One lockstep stream for ``seconds``: each frame's stages in ms, client's and service's, and its total;
    and the engine and precision that served it (what ``auto`` chose)."""
    rows = []
    served_by = ""
    with open_stream(url, output="depth", **options) as ws:
        start = time.perf_counter()
        while time.perf_counter() - start < seconds:
            marks = [time.perf_counter()]
            ws.send(frames[len(rows) % len(frames)])
            marks.append(time.perf_counter())
            header = json.loads(ws.recv(timeout=60))
            marks.append(time.perf_counter())
            bodies = [ws.recv(timeout=60) for _ in header["payloads"]]
            marks.append(time.perf_counter())
            depth_metres(header["payloads"][0], bodies[0])
            marks.append(time.perf_counter())
            row = {name: (marks[i + 1] - marks[i]) * 1000 for i, name in enumerate(CLIENT)}
            row["total"] = (marks[-1] - marks[0]) * 1000
            served_by = f"{header['engine']} {header['precision']}"
            served = {"queued": header["queued_ms"]} | header["stages_ms"]
            row |= {name: served.get(name, 0.0) for name in SERVICE}
            row[OTHER] = sum(ms for name, ms in served.items() if name not in SERVICE)
            # Can be below zero: the service starts on a frame while the client's send still returns.
            row[TRANSPORT] = row["wait for the header"] - sum(served.values())
            rows.append(row)
    return rows, served_by


def stage_table(label: str, rows: list[dict[str, float]]) -> str:
    """Median ms and share of the median frame for each stage; the network's share and what is outside it."""
    total = statistics.median(row["total"] for row in rows)

    def median(name: str) -> float:
        return statistics.median(row[name] for row in rows)

    lines = [
        f"| {label} ({len(rows)} frames, {1000 / total:.1f} frames/s) | median ms | share |",
        "|---|---|---|",
    ]
    lines.append(f"| client: send | {median('send'):.2f} | {median('send') / total:.0%} |")
    for name in SERVICE:
        lines.append(f"| service: {name} | {median(name):.2f} | {median(name) / total:.0%} |")
    lines.append(f"| service: {OTHER} | {median(OTHER):.2f} | {median(OTHER) / total:.0%} |")
    lines.append(f"| {TRANSPORT} | {median(TRANSPORT):.2f} | {median(TRANSPORT) / total:.0%} |")
    for name in CLIENT[2:]:
        lines.append(f"| client: {name} | {median(name):.2f} | {median(name) / total:.0%} |")
    outside = statistics.median(row["total"] - row["inference"] for row in rows)
    lines.append(f"| **outside the network** (total - inference) | {outside:.2f} | {outside / total:.0%} |")
    lines.append(f"| total, send to depth in metres | {total:.2f} | 100% |")
    return "\n".join(lines)


def stage_report(
    url: str, frames: list[bytes], seconds: float, models: list[str], closed: Callable[[str, object], object]
) -> str:
    """The stage table of each model, for ``png16`` and ``raw16`` depth."""
    tables = []
    for model in models:
        for encoding in ("png16", "raw16"):
            rows, served_by = frame_stages(url, frames, seconds, model=model, depth_encoding=encoding)
            closed(url, None)
            tables.append(stage_table(f"{model}, {served_by}, depth {encoding}", rows))
    return "\n\n".join(tables)
