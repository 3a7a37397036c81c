"""Prometheus metrics: requests and latency per route and model, inference time, the loaded models' memory."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, ProcessCollector
from starlette.types import ASGIApp, Message, Receive, Scope, Send

if TYPE_CHECKING:
    from app.catalog import ModelCatalog

LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30)


class ServiceMetrics:
    """One registry per app, so several apps (tests) never share counters."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "rgb2cloud_requests",
            "HTTP requests by route, method, status and model (NAME:VERSION; empty where none ran)",
            ["route", "method", "status", "model"],
            registry=self.registry,
        )
        self.latency = Histogram(
            "rgb2cloud_request_seconds",
            "HTTP request latency by route and model",
            ["route", "model"],
            buckets=LATENCY_BUCKETS,
            registry=self.registry,
        )
        self.inference = Histogram(
            "rgb2cloud_inference_seconds",
            "generator time per image, by model",
            ["model"],
            buckets=LATENCY_BUCKETS,
            registry=self.registry,
        )
        self.loaded = Gauge("rgb2cloud_models_loaded", "models loaded now", registry=self.registry)
        self.weights = Gauge(
            "rgb2cloud_model_weights_bytes", "weights held by each loaded model", ["model"], registry=self.registry
        )
        # process_resident_memory_bytes and friends: the whole process, all models included.
        ProcessCollector(registry=self.registry)
        self.in_flight = Gauge("rgb2cloud_inference_in_flight", "images being inferred now", registry=self.registry)
        self.queued = Gauge("rgb2cloud_inference_queued", "images waiting for the pool", registry=self.registry)
        self.streams_open = Gauge("rgb2cloud_streams_open", "WebSocket streams open now", registry=self.registry)
        self.streams_refused = Counter(
            "rgb2cloud_streams_refused",
            "streams refused at the door, full (closed with 1013) or origin (403, not allowed by CORS), or closed "
            "for not_reading their answers (1008)",
            ["reason"],
            registry=self.registry,
        )
        self.stream_frames = Counter(
            "rgb2cloud_stream_frames",
            "stream messages by outcome: frames received, answered, skipped (a newer frame replaced them while "
            "they waited), refused (an error of their own); bad_message: a text message that changed nothing",
            ["outcome"],
            registry=self.registry,
        )

    def models_changed(self, catalog: ModelCatalog) -> None:
        loaded = catalog.loaded()
        self.loaded.set(len(loaded))
        self.weights.clear()
        for model in loaded:
            self.weights.labels(model.label).set(model.weights_bytes)

    def pool_changed(self, running: int, waiting: int) -> None:
        self.in_flight.set(running)
        self.queued.set(waiting)


class MetricsMiddleware:
    """Counts and times every HTTP request under its route template (not the raw path) and the model that ran."""

    def __init__(self, app: ASGIApp, metrics: ServiceMetrics):
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status, model = 500, ""

        async def send_wrapper(message: Message) -> None:
            nonlocal status, model
            if message["type"] == "http.response.start":
                status = message["status"]
                headers = dict(message.get("headers", []))
                if b"x-model-name" in headers:
                    model = f"{headers[b'x-model-name'].decode()}:{headers.get(b'x-model-version', b'').decode()}"
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            route = scope.get("route")
            name = getattr(route, "path", None) or "unmatched"
            self.metrics.requests.labels(name, scope["method"], str(status), model).inc()
            self.metrics.latency.labels(name, model).observe(time.perf_counter() - start)
