"""What route handlers need, declared once as FastAPI dependencies.

``main.create_app`` puts the settings, the loaded model, the inference pool and the
metrics on ``app.state``; handlers ask for them by type (``SettingsDep``, ...), so
no handler reaches into the application's state itself, and tests can override any
of them with ``app.dependency_overrides``.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Request

from app.loading import LoadedModel
from app.observability import ServiceMetrics
from app.pool import InferencePool
from app.settings import Settings


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_model_if_loaded(request: Request) -> LoadedModel | None:
    """The model being served, or None while startup is still loading it."""
    return request.app.state.model


def get_model(request: Request) -> LoadedModel:
    """The model being served; 503 (retry shortly) until startup has loaded and warmed it."""
    model = request.app.state.model
    if model is None:
        raise HTTPException(503, "the model is not loaded yet", headers={"Retry-After": "1"})
    return model


def get_pool(request: Request) -> InferencePool:
    return request.app.state.pool


def get_metrics(request: Request) -> ServiceMetrics:
    return request.app.state.metrics


SettingsDep = Annotated[Settings, Depends(get_settings)]
ModelDep = Annotated[LoadedModel, Depends(get_model)]
MaybeModelDep = Annotated[LoadedModel | None, Depends(get_model_if_loaded)]
PoolDep = Annotated[InferencePool, Depends(get_pool)]
MetricsDep = Annotated[ServiceMetrics, Depends(get_metrics)]
