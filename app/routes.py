"""Thin handlers: read the upload, run the pipeline in the pool, return bytes + headers."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, File, Query, UploadFile
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from app.deps import MaybeModelDep, MetricsDep, ModelDep, PoolDep, SettingsDep
from app.loading import LoadedModel, available_models
from app.observability import ServiceMetrics
from app.pipeline import CloudOptions, Result, depth_png, point_cloud_ply
from app.pool import InferencePool

router = APIRouter()

IMAGE_FIELD = File(description="the photo: JPEG, PNG, WebP, TIFF, BMP or GIF (first frame); any size and mode")
PNG_RESPONSE = {200: {"content": {"image/png": {}}, "description": "depth PNG"}}
PLY_RESPONSE = {200: {"content": {"application/octet-stream": {}}, "description": "binary little-endian PLY"}}
ERRORS = {
    400: {"description": "empty, truncated or corrupt image"},
    413: {"description": "body or pixel count over the limit"},
    415: {"description": "not an image"},
    503: {"description": "busy (retry after Retry-After seconds) or not ready"},
}


async def _run(pool: InferencePool, metrics: ServiceMetrics, fn, model: LoadedModel, *args) -> Result:
    """Run one request's pipeline in the pool and add the timing headers."""
    result: Result = await pool.run(fn, model, *args)
    metrics.inference.observe(result.inference_seconds)
    result.headers["X-Inference-Ms"] = f"{result.inference_seconds * 1000:.1f}"
    result.headers["Server-Timing"] = result.server_timing()
    return result


@router.post("/depth", response_class=Response, responses={**PNG_RESPONSE, **ERRORS})
async def depth(
    model: ModelDep,
    settings: SettingsDep,
    pool: PoolDep,
    metrics: MetricsDep,
    image: Annotated[UploadFile, IMAGE_FIELD],
    format: Annotated[
        Literal["png16", "colormap"], Query(description="png16: 16-bit millimetres (default); colormap: preview")
    ] = "png16",
) -> Response:
    """Metric depth for the photo: 16-bit PNG in millimetres, 0 = no depth, at the photo's size."""
    data = await image.read()
    limits = settings.max_pixels, settings.inference_max_pixels
    result = await _run(pool, metrics, depth_png, model, data, *limits, format == "colormap")
    return Response(result.body, media_type="image/png", headers=result.headers)


@router.post("/pointcloud", response_class=Response, responses={**PLY_RESPONSE, **ERRORS})
async def pointcloud(
    model: ModelDep,
    settings: SettingsDep,
    pool: PoolDep,
    metrics: MetricsDep,
    image: Annotated[UploadFile, IMAGE_FIELD],
    fx: Annotated[float | None, Query(gt=0, allow_inf_nan=False, description="focal length x, input pixels")] = None,
    fy: Annotated[float | None, Query(gt=0, allow_inf_nan=False, description="focal length y, input pixels")] = None,
    cx: Annotated[float | None, Query(allow_inf_nan=False, description="principal point x, input pixels")] = None,
    cy: Annotated[float | None, Query(allow_inf_nan=False, description="principal point y, input pixels")] = None,
    stride: Annotated[int, Query(ge=1, le=64, description="keep every stride-th row and column")] = 1,
    min_depth: Annotated[float, Query(ge=0, allow_inf_nan=False, description="drop points nearer (m)")] = 0.0,
    max_depth: Annotated[float, Query(gt=0, allow_inf_nan=False, description="drop points farther (m)")] = 100.0,
) -> Response:
    """A coloured point cloud (formula (5): x right, y down, z forward, metres) as binary PLY."""
    if min_depth > max_depth:
        return JSONResponse({"detail": f"min_depth ({min_depth}) is greater than max_depth ({max_depth})"}, 422)
    options = CloudOptions(fx, fy, cx, cy, stride, min_depth, max_depth)
    data = await image.read()
    limits = settings.max_pixels, settings.inference_max_pixels
    result = await _run(pool, metrics, point_cloud_ply, model, data, *limits, options)
    return Response(result.body, media_type="application/octet-stream", headers=result.headers)


@router.get("/healthz")
async def healthz() -> dict[str, str]:
    """The process is alive."""
    return {"status": "ok"}


@router.get("/readyz", responses={503: {"description": "not ready"}})
async def readyz(model: MaybeModelDep) -> JSONResponse:
    """200 once the model is loaded, verified and warmed up."""
    if model is None:
        return JSONResponse({"status": "loading"}, 503)
    return JSONResponse({"status": "ready", "model": model.card.name, "version": model.card.version})


@router.get("/v1/models")
async def models(model: MaybeModelDep, settings: SettingsDep) -> dict:
    """The loaded model's card (null while loading), and every version in the registry."""
    return {
        "loaded": None if model is None else model.card.model_dump(mode="json"),
        "available": available_models(settings.registry),
    }


@router.get("/metrics", response_class=Response)
async def metrics(metrics: MetricsDep) -> Response:
    """Prometheus text format."""
    return Response(generate_latest(metrics.registry), media_type=CONTENT_TYPE_LATEST)
