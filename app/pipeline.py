"""One request's work as plain functions over arrays; each runs inside the inference pool."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from app.camera import CameraQuery, PhotoCamera, photo_camera
from app.imaging import encode_colormap_png, open_upload
from app.loading import LoadedModel
from app.temporal import TemporalFilter
from contract.encodings import depth_metres, depth_millimetres, encode_depth_png, encode_ply
from contract.geometry import point_cloud
from contract.resample import depth_to_photo, generator_size, to_model_camera
from contract.runtime import RunPrecision


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


@dataclass
class Inferred:
    """A decoded photo, its depth, the camera it was inferred with, and the generator's focal ratio."""

    #: The upright photo at its own size, or None where only its depth was asked for.
    rgb: np.ndarray | None
    depth: np.ndarray
    camera: PhotoCamera
    focal_ratio: float
    #: The precision that ran, and the one wanted (``auto``: whichever this version serves fastest here).
    precision: RunPrecision
    wanted: RunPrecision | Literal["auto"]

    def headers(self, model: LoadedModel) -> dict[str, str]:
        """Which model, precision, engine and camera made the depth; ``X-Focal-Ratio`` below 1 says the photo
        was shrunk further, and ``X-Precision-Fallback`` why the precision asked for is not served here."""
        headers = {
            "X-Model-Name": model.card.name,
            "X-Model-Version": model.card.version,
            "X-Precision": self.precision,
            "X-Engine": model.engines[self.precision],
            "X-Intrinsics": self.camera.header(),
            "X-Intrinsics-Source": self.camera.source,
            "X-Focal-Ratio": f"{self.focal_ratio:.4f}",
        }
        if self.wanted != "auto" and self.precision != self.wanted:
            headers["X-Precision-Fallback"] = f"{self.wanted} asked for; {model.unserved[self.wanted]}"
        return headers


def _photo_and_depth(
    model: LoadedModel,
    data: bytes,
    settings: RequestSettings,
    query: CameraQuery,
    watch: Stopwatch,
    colours: bool,
) -> Inferred:
    """The photo's depth at its own pixels; ``colours``: the photo at its own size too, for a point cloud.

    A JPEG the generator sees at exactly half its size is decoded at that size for the generator, whatever
    else is asked for, so that a photo's depth is the same from every route (``app.imaging.Upload.rgb``).
    """
    upload = open_upload(data, settings.max_pixels, settings.subject)
    width, height = upload.size
    camera = photo_camera(model.card.camera, width, height, query, upload.exif_focal)
    size, ratio = generator_size(camera.intrinsics, model.card.camera, settings.inference_max_pixels)
    shown = upload.rgb(size)
    at_own_size = shown.shape[:2] == (height, width)
    rgb = (shown if at_own_size else upload.rgb()) if colours else None
    watch.lap("decode")
    precision = model.serving(settings.precision)
    # The one rescale rule (contract.resample), a stage at a time: the photo to the model's focal length, the
    # generator (to metres), and its depth back at the photo's pixels. The photo's resample is nothing where its
    # camera is the model's or it was decoded at the generator's size; the depth's, where its camera is the model's.
    seen = (
        to_model_camera(shown, camera.intrinsics, model.card.camera, settings.inference_max_pixels)[0]
        if at_own_size
        else shown
    )
    watch.lap("resample")
    depth = model.predict_depth(seen, precision)
    watch.lap("inference")
    depth = depth_to_photo(depth, camera.intrinsics)
    watch.lap("resample_back")
    return Inferred(rgb, depth, camera, ratio, precision, settings.precision)


@dataclass(frozen=True)
class RequestSettings:
    """The settings that bound one request's work, and the generator precision it wants."""

    max_pixels: int
    inference_max_pixels: int
    precision: RunPrecision | Literal["auto"] = "auto"
    #: What the image is called in errors: the upload's form field, or a stream's frame.
    subject: str = "the 'image' field"


def depth_png(model: LoadedModel, data: bytes, settings: RequestSettings, query: CameraQuery, colormap: bool) -> Result:
    watch = Stopwatch()
    inferred = _photo_and_depth(model, data, settings, query, watch, colours=False)
    depth, headers = inferred.depth, inferred.headers(model)
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
    stride: int
    min_depth: float
    max_depth: float


def point_cloud_ply(
    model: LoadedModel, data: bytes, settings: RequestSettings, query: CameraQuery, options: CloudOptions
) -> Result:
    """Formula (5) with the photo's own camera: the one its depth was inferred with."""
    watch = Stopwatch()
    inferred = _photo_and_depth(model, data, settings, query, watch, colours=True)
    assert inferred.rgb is not None
    k = inferred.camera.intrinsics
    points = point_cloud(
        inferred.depth, inferred.rgb, k, stride=options.stride, min_depth=options.min_depth, max_depth=options.max_depth
    )
    watch.lap("backproject")
    body = encode_ply(points)
    watch.lap("encode")
    headers = inferred.headers(model) | {"X-Point-Count": str(len(points))}
    return Result(body, headers, watch.stages)


@dataclass(frozen=True)
class FrameOptions:
    """What a stream asks of each frame: which outputs, in which encodings, and the point cloud's bounds."""

    output: Literal["depth", "pointcloud", "both"]
    depth_encoding: Literal["png16", "raw16", "raw32"]
    cloud_encoding: Literal["ply", "raw"]
    cloud: CloudOptions


@dataclass
class StreamFrame:
    """One stream frame's answer: its payloads in order, each ``(kind, encoding, bytes)``, and the facts
    its header reports (``Inferred.headers``, the point count) with the seconds each stage took."""

    payloads: list[tuple[str, str, bytes]]
    headers: dict[str, str]
    camera: PhotoCamera
    stages: dict[str, float]
    points: int | None


def raw_cloud(points: np.ndarray) -> bytes:
    """The raw point cloud: every point's float32 x, y, z (little-endian), then every point's uint8 r, g, b.

    Two blocks rather than PLY's interleaved records, so a browser views them as a ``Float32Array`` and a
    ``Uint8Array`` without copying (the first block is 12 bytes a point, so the second stays aligned).
    """
    xyz = np.stack([points["x"], points["y"], points["z"]], axis=1).astype("<f4", copy=False)
    rgb = np.stack([points["red"], points["green"], points["blue"]], axis=1)
    return xyz.tobytes() + rgb.tobytes()


def stream_frame(
    model: LoadedModel,
    data: bytes,
    settings: RequestSettings,
    query: CameraQuery,
    options: FrameOptions,
    smoother: TemporalFilter | None,
) -> StreamFrame:
    """One frame of a stream (``app.stream``): the depth and point cloud of ``/depth`` and ``/pointcloud``
    from one inference, in the encodings the stream asked for, through the stream's temporal filter if any."""
    watch = Stopwatch()
    cloud = options.output in ("pointcloud", "both")
    inferred = _photo_and_depth(model, data, settings, query, watch, colours=cloud)
    if smoother is not None:
        inferred.depth = smoother.apply(inferred.depth)
        watch.lap("smooth")
    payloads: list[tuple[str, str, bytes]] = []
    count = None
    if options.output in ("depth", "both"):
        if options.depth_encoding == "png16":
            payloads.append(("depth", "png16", encode_depth_png(inferred.depth)))
        elif options.depth_encoding == "raw16":
            payloads.append(("depth", "raw16", depth_millimetres(inferred.depth).tobytes()))
        else:
            payloads.append(("depth", "raw32", depth_metres(inferred.depth).tobytes()))
        watch.lap("encode")
    if cloud:
        assert inferred.rgb is not None
        bounds = options.cloud
        points = point_cloud(
            inferred.depth,
            inferred.rgb,
            inferred.camera.intrinsics,
            stride=bounds.stride,
            min_depth=bounds.min_depth,
            max_depth=bounds.max_depth,
        )
        watch.lap("backproject")
        count = len(points)
        body = encode_ply(points) if options.cloud_encoding == "ply" else raw_cloud(points)
        payloads.append(("pointcloud", options.cloud_encoding, body))
        watch.lap("encode_cloud")
    return StreamFrame(payloads, inferred.headers(model), inferred.camera, watch.stages, count)
