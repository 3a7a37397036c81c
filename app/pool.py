"""Inference off the event loop, in a bounded pool, with a bounded queue in front of it.

Requests beyond ``workers + max_queue`` are refused at once (503 + Retry-After)
instead of piling up: latency stays bounded and memory flat under overload.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")


class Overloaded(Exception):
    """The queue is full; the client should retry later."""


class InferencePool:
    def __init__(self, workers: int, max_queue: int, on_change: Callable[[int, int], None] = lambda a, q: None):
        self.workers = workers
        self.capacity = workers + max_queue
        self._executor = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="inference")
        self._lock = threading.Lock()
        self._admitted = 0  # running + waiting
        self._running = 0
        self._on_change = on_change

    def _report(self) -> None:
        self._on_change(self._running, self._admitted - self._running)

    async def run(self, fn: Callable[..., T], *args) -> T:
        """Run ``fn(*args)`` in the pool, or raise ``Overloaded`` at once if the queue is full."""
        with self._lock:
            if self._admitted >= self.capacity:
                raise Overloaded()
            self._admitted += 1
            self._report()

        def call() -> T:
            with self._lock:
                self._running += 1
                self._report()
            try:
                return fn(*args)
            finally:
                with self._lock:
                    self._running -= 1
                    self._admitted -= 1
                    self._report()

        future = self._executor.submit(call)
        try:
            return await asyncio.wrap_future(future)
        except asyncio.CancelledError:
            if future.cancel():  # the client left before the job started: free its place
                with self._lock:
                    self._admitted -= 1
                    self._report()
            raise

    def shutdown(self) -> None:
        self._executor.shutdown(wait=True, cancel_futures=True)
