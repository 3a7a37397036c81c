"""Thin handlers: read the upload, run the pipeline in the pool, return bytes + headers."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, File, Query, UploadFile
from fastapi.responses import FileResponse, JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest
from starlette.concurrency import run_in_threadpool

from app.deps import CameraDep, CatalogDep, MetricsDep, ModelDep, PoolDep, RequestSettingsDep
from app.loading import LoadedModel
from app.observability import ServiceMetrics
from app.pipeline import CloudOptions, Result, depth_png, point_cloud_ply
from app.pool import InferencePool

router = APIRouter()
#: The web page: static files that call the API like any other client.
WEB_DIR = Path(__file__).with_name("web")

IMAGE_FIELD = File(description="the photo: JPEG, PNG, WebP, TIFF, BMP or GIF (first frame); any size and mode")
PNG_RESPONSE = {200: {"content": {"image/png": {}}, "description": "depth PNG"}}
PLY_RESPONSE = {200: {"content": {"application/octet-stream": {}}, "description": "binary little-endian PLY"}}
ERRORS = {
    400: {"description": "empty, truncated or corrupt image"},
    404: {"description": "no such model or version; the body lists what the registry holds"},
    409: {
        "description": "the model version is in the registry but fails verification, or precision=int8 names a "
        "graph that disagrees with fp32 on this machine; the body says why"
    },
    413: {"description": "body or pixel count over the limit"},
    415: {"description": "not an image"},
    422: {"description": "a query parameter out of range"},
    503: {"description": "busy (retry after Retry-After seconds) or not ready"},
}


async def _run(pool: InferencePool, metrics: ServiceMetrics, fn, model: LoadedModel, *args) -> Result:
    """Run one request's pipeline in the pool and add the timing headers."""
    result: Result = await pool.run(fn, model, *args)
    metrics.inference.labels(model.label).observe(result.inference_seconds)
    result.headers["X-Inference-Ms"] = f"{result.inference_seconds * 1000:.1f}"
    result.headers["Server-Timing"] = result.server_timing()
    return result


@router.post("/depth", response_class=Response, responses={**PNG_RESPONSE, **ERRORS})
async def depth(
    model: ModelDep,
    camera: CameraDep,
    settings: RequestSettingsDep,
    pool: PoolDep,
    metrics: MetricsDep,
    image: Annotated[UploadFile, IMAGE_FIELD],
    format: Annotated[
        Literal["png16", "colormap"], Query(description="png16: 16-bit millimetres (default); colormap: preview")
    ] = "png16",
) -> Response:
    """Metric depth for the photo: 16-bit PNG in millimetres, 0 = no depth, at the photo's size.

    The photo is resampled to the model's focal length first (``X-Intrinsics-Source`` says whose).
    """
    data = await image.read()
    result = await _run(pool, metrics, depth_png, model, data, settings, camera, format == "colormap")
    return Response(result.body, media_type="image/png", headers=result.headers)


@router.post("/pointcloud", response_class=Response, responses={**PLY_RESPONSE, **ERRORS})
async def pointcloud(
    model: ModelDep,
    camera: CameraDep,
    settings: RequestSettingsDep,
    pool: PoolDep,
    metrics: MetricsDep,
    image: Annotated[UploadFile, IMAGE_FIELD],
    stride: Annotated[int, Query(ge=1, le=64, description="keep every stride-th row and column")] = 1,
    min_depth: Annotated[float, Query(ge=0, allow_inf_nan=False, description="drop points nearer (m)")] = 0.0,
    max_depth: Annotated[float, Query(gt=0, allow_inf_nan=False, description="drop points farther (m)")] = 100.0,
) -> Response:
    """A coloured point cloud (formula (5): x right, y down, z forward, metres) as binary PLY.

    Back-projected with the camera the depth was inferred for (``X-Intrinsics``).
    """
    if min_depth > max_depth:
        return JSONResponse({"detail": f"min_depth ({min_depth}) is greater than max_depth ({max_depth})"}, 422)
    options = CloudOptions(stride, min_depth, max_depth)
    data = await image.read()
    result = await _run(pool, metrics, point_cloud_ply, model, data, settings, camera, options)
    return Response(result.body, media_type="application/octet-stream", headers=result.headers)


@router.get("/", include_in_schema=False)
async def page() -> FileResponse:
    """The web page: a photo in, its depth and an interactive point cloud out, through this API."""
    return FileResponse(WEB_DIR / "index.html")


@router.get("/healthz")
async def healthz() -> dict[str, str]:
    """The process is alive."""
    return {"status": "ok"}


@router.get("/readyz", responses={503: {"description": "not ready"}})
async def readyz(catalog: CatalogDep) -> JSONResponse:
    """200 once the default model is loaded, verified and warmed up; other models never make it unready."""
    model = catalog.default
    if model is None:
        return JSONResponse({"status": "loading"}, 503)
    return JSONResponse({"status": "ready", "model": model.card.name, "version": model.card.version})


@router.get("/v1/models")
async def models(catalog: CatalogDep) -> dict:
    """Every model and version in the registry: loaded or not, refused with the reason, and its card's summary."""
    return await run_in_threadpool(catalog.describe)


@router.get("/metrics", response_class=Response)
async def metrics(metrics: MetricsDep) -> Response:
    """Prometheus text format."""
    return Response(generate_latest(metrics.registry), media_type=CONTENT_TYPE_LATEST)
