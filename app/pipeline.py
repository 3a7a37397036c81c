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
from model.geometry import Intrinsics, point_cloud


@dataclass
class Result:
    body: bytes
    headers: dict[str, str]
    inference_seconds: float


def infer(model: LoadedModel, rgb: np.ndarray, max_pixels: int) -> tuple[np.ndarray, float]:
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
    start = time.perf_counter()
    depth = model.predict_depth(small)
    seconds = time.perf_counter() - start
    if small is not rgb:
        depth = np.asarray(Image.fromarray(depth, mode="F").resize((w, h), Image.BILINEAR), dtype=np.float32)
    return depth, seconds


def model_headers(model: LoadedModel) -> dict[str, str]:
    return {"X-Model-Name": model.card.name, "X-Model-Version": model.card.version}


def depth_png(model: LoadedModel, data: bytes, max_pixels: int, infer_pixels: int, colormap: bool) -> Result:
    rgb = decode_image(data, max_pixels)
    depth, seconds = infer(model, rgb, infer_pixels)
    headers = model_headers(model)
    if colormap:
        lo, hi = (float(v) for v in np.percentile(depth, [2, 98]))
        headers |= {"X-Depth-Units": "colormap", "X-Depth-Range-M": f"{lo:.3f},{hi:.3f}"}
        return Result(encode_colormap_png(depth, lo, hi), headers, seconds)
    headers["X-Depth-Units"] = "mm"
    return Result(encode_depth_png(depth), headers, seconds)


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
    rgb = decode_image(data, max_pixels)
    depth, seconds = infer(model, rgb, infer_pixels)
    k = camera_for(model, rgb.shape[1], rgb.shape[0], options)
    points = point_cloud(depth, rgb, k, stride=options.stride, min_depth=options.min_depth, max_depth=options.max_depth)
    headers = model_headers(model) | {
        "X-Point-Count": str(len(points)),
        "X-Intrinsics": f"{k.fx:.4f},{k.fy:.4f},{k.cx:.4f},{k.cy:.4f}",
    }
    return Result(encode_ply(points), headers, seconds)
