"""What route handlers need, declared once as FastAPI dependencies.

``main.create_app`` puts the settings, the model catalog, the inference pool and the
metrics on ``app.state``; handlers ask for them by type (``SettingsDep``, ...), so
no handler reaches into the application's state itself, and tests can override any
of them with ``app.dependency_overrides``.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import Depends, HTTPException, Query, Request
from starlette.concurrency import run_in_threadpool

from app.camera import CameraQuery
from app.catalog import ModelCatalog
from app.loading import LoadedModel
from app.observability import ServiceMetrics
from app.pipeline import RequestSettings
from app.pool import InferencePool
from app.settings import Settings
from contract.runtime import RunPrecision

MODEL_REFERENCE = r"^[A-Za-z0-9][A-Za-z0-9._-]*(:[0-9A-Za-z.+-]+)?$"


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_catalog(request: Request) -> ModelCatalog:
    return request.app.state.catalog


SettingsDep = Annotated[Settings, Depends(get_settings)]
CatalogDep = Annotated[ModelCatalog, Depends(get_catalog)]


async def get_model(
    catalog: CatalogDep,
    model: Annotated[
        str | None,
        Query(
            description="NAME (its newest version) or NAME:VERSION from /v1/models; default: the service's default",
            max_length=200,
            pattern=MODEL_REFERENCE,
        ),
    ] = None,
) -> LoadedModel:
    """The model the request names, loaded on first use; 503 (retry shortly) until the default is loaded."""
    if model is not None:
        return await run_in_threadpool(catalog.get, model)  # loading takes seconds: never on the event loop
    if catalog.default is None:
        raise HTTPException(503, "the model is not loaded yet", headers={"Retry-After": "1"})
    return catalog.default


#: Focal lengths and principal points far outside any camera are refused, so every answer stays finite.
FOCAL_RANGE = {"ge": 0.01, "le": 1e7}
CENTRE_RANGE = {"ge": -1e7, "le": 1e7}


def camera_query(
    fx: Annotated[
        float | None,
        Query(**FOCAL_RANGE, allow_inf_nan=False, description="focal length x in the photo's pixels (fy alone: same)"),
    ] = None,
    fy: Annotated[
        float | None,
        Query(**FOCAL_RANGE, allow_inf_nan=False, description="focal length y in the photo's pixels (fx alone: same)"),
    ] = None,
    cx: Annotated[float | None, Query(**CENTRE_RANGE, allow_inf_nan=False, description="principal point x")] = None,
    cy: Annotated[float | None, Query(**CENTRE_RANGE, allow_inf_nan=False, description="principal point y")] = None,
) -> CameraQuery:
    """The photo's camera as the request gives it; the focal length otherwise comes from EXIF or the model."""
    return CameraQuery(fx, fy, cx, cy)


def get_request_settings(
    settings: SettingsDep,
    model: Annotated[LoadedModel, Depends(get_model)],
    precision: Annotated[
        RunPrecision | Literal["auto"] | None,
        Query(
            description="how the generator runs: fp32; bf16 where this CPU has bf16 units; int8 where the version "
            "ships an int8 graph; auto, the faster of fp32 and bf16 (default: RGB2CLOUD_PRECISION). X-Precision "
            "names the one that ran and X-Engine the engine"
        ),
    ] = None,
) -> RequestSettings:
    """The size limits a request's image is held to, from the settings, and the precision it wants.

    A request that names a precision this version may not serve here because it failed its check (int8 or
    bf16 depth that disagrees with fp32 on this machine) gets 409: it asked for it, and would get other depth.
    Without ``precision=`` the settings' precision falls back to fp32, and the response says why.
    """
    if precision is not None and precision in model.disagrees:
        raise HTTPException(
            409,
            f"precision={precision}: {model.label}: {model.unserved[precision]}; use precision=fp32",
        )
    return RequestSettings(settings.max_pixels, settings.inference_max_pixels, precision or settings.precision)


def get_pool(request: Request) -> InferencePool:
    return request.app.state.pool


def get_metrics(request: Request) -> ServiceMetrics:
    return request.app.state.metrics


ModelDep = Annotated[LoadedModel, Depends(get_model)]
PoolDep = Annotated[InferencePool, Depends(get_pool)]
CameraDep = Annotated[CameraQuery, Depends(camera_query)]
RequestSettingsDep = Annotated[RequestSettings, Depends(get_request_settings)]
MetricsDep = Annotated[ServiceMetrics, Depends(get_metrics)]
