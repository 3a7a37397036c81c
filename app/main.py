"""Assemble the app: settings, model loading at startup, middleware, routes.

uvicorn --factory app.main:create_app        # or: python -m app
"""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager

from fastapi import FastAPI, Request
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse

from app.imaging import BadImage
from app.limits import BodySizeLimit
from app.loading import LoadedModel, load_model
from app.observability import MetricsMiddleware, ServiceMetrics
from app.pool import InferencePool, Overloaded
from app.routes import router
from app.settings import Settings

log = logging.getLogger("rgb2cloud")
EXPOSED_HEADERS = [
    "X-Model-Name",
    "X-Model-Version",
    "X-Depth-Units",
    "X-Depth-Range-M",
    "X-Point-Count",
    "X-Intrinsics",
    "X-Inference-Ms",
    "Server-Timing",
    "Retry-After",
]


def create_app(settings: Settings | None = None, model: LoadedModel | None = None) -> FastAPI:
    """The app; it loads (or takes) the model, verified and warmed, before serving."""
    settings = settings or Settings()
    metrics = ServiceMetrics()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if app.state.model is None:
            app.state.model = load_model(settings)  # a ModelLoadError stops startup
        card = app.state.model.card
        log.info(
            "serving %s %s from %s (%s, warm-up %.2fs)",
            card.name,
            card.version,
            app.state.model.path,
            settings.backend,
            app.state.model.warmup_seconds,
        )
        yield
        app.state.pool.shutdown()

    app = FastAPI(
        title="rgb2cloud",
        version="0.1.0",
        summary="Metric depth and coloured point clouds from one RGB photo.",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.metrics = metrics
    app.state.model = model
    app.state.pool = InferencePool(settings.workers, settings.max_queue, metrics.pool_changed)

    @app.exception_handler(BadImage)
    async def bad_image(_: Request, error: BadImage) -> JSONResponse:
        return JSONResponse({"detail": error.message}, error.status)

    @app.exception_handler(Overloaded)
    async def overloaded(_: Request, __: Overloaded) -> JSONResponse:
        return JSONResponse(
            {"detail": "busy: the inference queue is full, retry shortly"},
            503,
            headers={"Retry-After": str(settings.retry_after_s)},
        )

    app.include_router(router)
    # The last added is the outermost: CORS wraps everything, so browsers can read even a 413.
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_upload_bytes)
    app.add_middleware(MetricsMiddleware, metrics=metrics)
    app.add_middleware(
        CORSMiddleware,
        allow_origins=settings.cors_origins,
        allow_methods=["GET", "POST"],
        allow_headers=["*"],
        expose_headers=EXPOSED_HEADERS,
    )
    return app
