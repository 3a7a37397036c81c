"""Assemble the app: settings, model loading at startup, middleware, routes.

uvicorn --factory app.main:create_app        # or: python -m app
"""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager
from importlib.metadata import version

from fastapi import FastAPI, Request
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from app.catalog import ModelCatalog, RefusedModel, UnknownModel
from app.imaging import BadImage
from app.limits import BodySizeLimit
from app.observability import MetricsMiddleware, ServiceMetrics
from app.pool import InferencePool, Overloaded
from app.routes import WEB_DIR, router
from app.settings import Settings
from app.stream import OpenStreams
from app.stream import router as stream_router

log = logging.getLogger("rgb2cloud")
EXPOSED_HEADERS = [
    "X-Model-Name",
    "X-Model-Version",
    "X-Depth-Units",
    "X-Depth-Range-M",
    "X-Point-Count",
    "X-Intrinsics",
    "X-Intrinsics-Source",
    "X-Focal-Ratio",
    "X-Precision",
    "X-Precision-Fallback",
    "X-Engine",
    "X-Inference-Ms",
    "Server-Timing",
    "Retry-After",
]


def create_app(settings: Settings | None = None, catalog: ModelCatalog | None = None) -> FastAPI:
    """The app; it loads the default model (unless ``catalog`` has), verified and warmed, before serving."""
    settings = settings or Settings()
    metrics = ServiceMetrics()
    catalog = catalog or ModelCatalog(settings)
    catalog.on_change = metrics.models_changed

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        default = catalog.default or catalog.load_default()  # a ModelLoadError stops startup
        metrics.models_changed(catalog)
        log.info(
            "serving %s from %s (%s, warm-up %.2fs; other models load on first use, at most %d at once)",
            default.label,
            default.path,
            ", ".join(f"{p} on {e}" for p, e in default.engines.items()),
            default.warmup_seconds,
            settings.max_loaded,
        )
        yield
        app.state.pool.shutdown()

    app = FastAPI(
        title="rgb2cloud",
        version=version("rgb2cloud"),
        summary="Metric depth and coloured point clouds from one RGB photo.",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.metrics = metrics
    app.state.catalog = catalog
    app.state.pool = InferencePool(settings.workers, settings.max_queue, metrics.pool_changed)
    app.state.streams = OpenStreams(settings.max_streams, metrics)

    @app.exception_handler(BadImage)
    async def bad_image(_: Request, error: BadImage) -> JSONResponse:
        return JSONResponse({"detail": error.message}, error.status)

    @app.exception_handler(UnknownModel)
    async def unknown_model(_: Request, error: UnknownModel) -> JSONResponse:
        return JSONResponse({"detail": error.message, "available": error.available}, 404)

    @app.exception_handler(RefusedModel)
    async def refused_model(_: Request, error: RefusedModel) -> JSONResponse:
        return JSONResponse({"detail": error.message}, 409)

    @app.exception_handler(Overloaded)
    async def overloaded(_: Request, __: Overloaded) -> JSONResponse:
        return JSONResponse(
            {"detail": "busy: the inference queue is full, retry shortly"},
            503,
            headers={"Retry-After": str(settings.retry_after_s)},
        )

    app.include_router(router)
    app.include_router(stream_router)
    app.mount("/web", StaticFiles(directory=WEB_DIR), name="web")
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
