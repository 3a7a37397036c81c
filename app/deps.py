"""What route handlers need, declared once as FastAPI dependencies.

``main.create_app`` puts the settings, the model catalog, the inference pool and the
metrics on ``app.state``; handlers ask for them by type (``SettingsDep``, ...), so
no handler reaches into the application's state itself, and tests can override any
of them with ``app.dependency_overrides``.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Query, Request
from starlette.concurrency import run_in_threadpool

from app.catalog import ModelCatalog
from app.loading import LoadedModel
from app.observability import ServiceMetrics
from app.pool import InferencePool
from app.settings import Settings

MODEL_REFERENCE = r"^[A-Za-z0-9][A-Za-z0-9._-]*(:[0-9A-Za-z.+-]+)?$"


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_catalog(request: Request) -> ModelCatalog:
    return request.app.state.catalog


async def get_model(
    request: Request,
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
    catalog: ModelCatalog = request.app.state.catalog
    if model is not None:
        return await run_in_threadpool(catalog.get, model)  # loading takes seconds: never on the event loop
    if catalog.default is None:
        raise HTTPException(503, "the model is not loaded yet", headers={"Retry-After": "1"})
    return catalog.default


def get_pool(request: Request) -> InferencePool:
    return request.app.state.pool


def get_metrics(request: Request) -> ServiceMetrics:
    return request.app.state.metrics


SettingsDep = Annotated[Settings, Depends(get_settings)]
CatalogDep = Annotated[ModelCatalog, Depends(get_catalog)]
ModelDep = Annotated[LoadedModel, Depends(get_model)]
PoolDep = Annotated[InferencePool, Depends(get_pool)]
MetricsDep = Annotated[ServiceMetrics, Depends(get_metrics)]
