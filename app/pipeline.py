"""One request's work as plain functions over arrays; each runs inside the inference pool."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from PIL import Image

from app.imaging import decode_image, encode_colormap_png, encode_depth_png
from app.loading import LoadedModel
from app.ply import encode_ply
from contract.geometry import Intrinsics, point_cloud


@dataclass
class Result:
    """The response body and headers, and the seconds each stage took on the server."""

    body: bytes
    headers: dict[str, str]
    stages: dict[str, float]

    @property
    def inference_seconds(self) -> float:
        return self.stages["inference"]

    def server_timing(self) -> str:
        """The standard ``Server-Timing`` header value (milliseconds; browsers' dev tools show it)."""
        return ", ".join(f"{name};dur={seconds * 1000:.1f}" for name, seconds in self.stages.items())


class Stopwatch:
    """Seconds per named stage, in the order the stages ran."""

    def __init__(self) -> None:
        self.stages: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.stages[name] = now - self._last
        self._last = now


def infer(model: LoadedModel, rgb: np.ndarray, max_pixels: int) -> np.ndarray:
    """Depth in metres at the input's size.

    Images above ``max_pixels`` are shrunk for the generator (it was trained near
    640x480; bigger inputs cost time without adding context) and the depth is
    resized back, so the output always has the input's size.
    """
    h, w = rgb.shape[:2]
    small = rgb
    if h * w > max_pixels:
        s = math.sqrt(max_pixels / (h * w))
        small = np.asarray(Image.fromarray(rgb).resize((max(1, round(w * s)), max(1, round(h * s))), Image.BILINEAR))
    depth = model.predict_depth(small)
    if small is not rgb:
        depth = np.asarray(Image.fromarray(depth, mode="F").resize((w, h), Image.BILINEAR), dtype=np.float32)
    return depth


def model_headers(model: LoadedModel) -> dict[str, str]:
    return {"X-Model-Name": model.card.name, "X-Model-Version": model.card.version}


def depth_png(model: LoadedModel, data: bytes, max_pixels: int, infer_pixels: int, colormap: bool) -> Result:
    watch = Stopwatch()
    rgb = decode_image(data, max_pixels)
    watch.lap("decode")
    depth = infer(model, rgb, infer_pixels)
    watch.lap("inference")
    headers = model_headers(model)
    if colormap:
        lo, hi = (float(v) for v in np.percentile(depth, [2, 98]))
        headers |= {"X-Depth-Units": "colormap", "X-Depth-Range-M": f"{lo:.3f},{hi:.3f}"}
        body = encode_colormap_png(depth, lo, hi)
    else:
        headers["X-Depth-Units"] = "mm"
        body = encode_depth_png(depth)
    watch.lap("encode")
    return Result(body, headers, watch.stages)


@dataclass(frozen=True)
class CloudOptions:
    fx: float | None
    fy: float | None
    cx: float | None
    cy: float | None
    stride: int
    min_depth: float
    max_depth: float


def camera_for(model: LoadedModel, width: int, height: int, options: CloudOptions) -> Intrinsics:
    """The card's training camera scaled to this image; any given fx/fy/cx/cy wins."""
    c = model.card.camera
    base = Intrinsics(c.fx, c.fy, c.cx, c.cy, c.width, c.height).resized(width, height)
    return Intrinsics(
        options.fx if options.fx is not None else base.fx,
        options.fy if options.fy is not None else base.fy,
        options.cx if options.cx is not None else base.cx,
        options.cy if options.cy is not None else base.cy,
        width,
        height,
    )


def point_cloud_ply(
    model: LoadedModel, data: bytes, max_pixels: int, infer_pixels: int, options: CloudOptions
) -> Result:
    watch = Stopwatch()
    rgb = decode_image(data, max_pixels)
    watch.lap("decode")
    depth = infer(model, rgb, infer_pixels)
    watch.lap("inference")
    k = camera_for(model, rgb.shape[1], rgb.shape[0], options)
    points = point_cloud(depth, rgb, k, stride=options.stride, min_depth=options.min_depth, max_depth=options.max_depth)
    watch.lap("backproject")
    body = encode_ply(points)
    watch.lap("encode")
    headers = model_headers(model) | {
        "X-Point-Count": str(len(points)),
        "X-Intrinsics": f"{k.fx:.4f},{k.fy:.4f},{k.cx:.4f},{k.cy:.4f}",
    }
    return Result(body, headers, watch.stages)
