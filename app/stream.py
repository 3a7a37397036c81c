"""``WebSocket /v1/stream``: a camera's frames in, depth and point clouds out, the latest frame first.

A camera sends faster than a 2-core CPU infers, so a stream holds at most one frame waiting: a newer
frame replaces it, and the next answer counts the frames skipped. A fast sender gets the freshest depth
at the model's own rate instead of a delay that grows. Each frame is one job in the same inference pool
as the POST routes, and a stream never has more than one there, so four busy streams queue a POST
behind four jobs at most. The protocol is in docs/api.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from app.catalog import ModelCatalog
from app.imaging import BadImage
from app.loading import LoadedModel
from app.observability import ServiceMetrics
from app.pipeline import RequestSettings, StreamFrame, stream_frame
from app.pool import InferencePool, Overloaded
from app.settings import Settings
from app.stream_options import OptionsError, StreamOptions, parse_options, resolve
from app.temporal import TemporalFilter

log = logging.getLogger("rgb2cloud")
router = APIRouter()
#: The WebSocket layer reads frames up to this many times ``stream_max_frame_bytes``, so that a frame over
#: the stream's limit gets an error of its own; a larger message closes the stream (1009).
STREAM_TRANSPORT_FACTOR = 4
#: Close codes (RFC 6455): the service is full (try again later), idle, a policy refused, a server fault.
TRY_AGAIN_LATER, GOING_AWAY, POLICY, SERVER_ERROR = 1013, 1001, 1008, 1011
#: Acknowledgements and errors (small JSON messages) a stream may owe its client before it is closed for
#: sending text messages faster than it reads their answers.
NOTICES_OWED = 16


class NotReading(Exception):
    """The client stopped reading: what it is owed cannot be sent, and would only pile up."""


def origin_allowed(origin: str | None, host: str | None, allowed: list[str]) -> bool:
    """Browsers apply no CORS to WebSockets, so the service does: a page may open a stream if its origin is
    one the CORS setting allows, or if this service served it (its origin is the Host it connects to) at an
    IP address or ``localhost``. A page at a domain name must be listed: its name could be re-pointed at this
    machine (DNS rebinding) by whoever owns it. Clients that are not browsers send no Origin and are not asked.
    """
    if origin is None:
        return True
    if "*" in allowed or origin in allowed:
        return True
    if host is None or urlsplit(origin).netloc.lower() != host.lower():
        return False
    name = (urlsplit(f"//{host}").hostname or "").lower()
    if name == "localhost":
        return True
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


@dataclass
class Frame:
    seq: int
    data: bytes
    received: float


class Mailbox:
    """The one frame a stream holds waiting: a newer frame replaces it, and the replaced one is counted."""

    def __init__(self) -> None:
        self._frame: Frame | None = None
        self._ready = asyncio.Event()
        self.skipped = 0

    def put(self, frame: Frame) -> bool:
        """Leave ``frame`` to be answered next; True if it replaced one that now never will be."""
        replaced = self._frame is not None
        self.skipped += replaced
        self._frame = frame
        self._ready.set()
        return replaced

    async def take(self) -> Frame:
        await self._ready.wait()
        self._ready.clear()
        frame, self._frame = self._frame, None
        assert frame is not None
        return frame


class OpenStreams:
    """How many streams are open, against ``max_streams``."""

    def __init__(self, limit: int, metrics: ServiceMetrics):
        self.limit = limit
        self.count = 0
        self._metrics = metrics

    def try_open(self) -> bool:
        if self.count >= self.limit:
            return False
        self.count += 1
        self._metrics.streams_open.set(self.count)
        return True

    def close(self) -> None:
        self.count -= 1
        self._metrics.streams_open.set(self.count)


class Stream:
    """One open stream: its options, its mailbox, and the two loops that read frames and answer them."""

    def __init__(self, socket: WebSocket, options: StreamOptions, model: LoadedModel, request: RequestSettings):
        state = socket.app.state
        self.socket = socket
        self.settings: Settings = state.settings
        self.catalog: ModelCatalog = state.catalog
        self.pool: InferencePool = state.pool
        self.metrics: ServiceMetrics = state.metrics
        self.options, self.model, self.request = options, model, request
        self.mailbox = Mailbox()
        self.smoother = self._smoother()
        self._send_lock = asyncio.Lock()
        #: What the reader owes the client (option acknowledgements, errors without a frame), sent by a task
        #: of its own so that the reader never waits on a client that does not read.
        self.notices: asyncio.Queue[dict[str, Any]] = asyncio.Queue(NOTICES_OWED)

    def _smoother(self) -> TemporalFilter | None:
        return TemporalFilter() if self.options.smooth == "temporal" else None

    async def send(self, header: dict[str, Any], payloads: Sequence[bytes] = ()) -> None:
        """A JSON header and the binary messages it announces, never interleaved with another answer.

        A client that takes none of it for ``stream_send_timeout_s`` has stopped reading: ``NotReading``.
        """
        async with self._send_lock:
            try:
                async with asyncio.timeout(self.settings.stream_send_timeout_s):
                    await self.socket.send_text(json.dumps(header))
                    for payload in payloads:
                        await self.socket.send_bytes(payload)
            except TimeoutError:
                raise NotReading(
                    f"not reading: an answer waited {self.settings.stream_send_timeout_s:g} s to be taken"
                ) from None

    async def refuse(self, status: int, detail: str, seq: int | None = None) -> None:
        """A frame's error, in order with the answers (the answerer's), or one owed to a message (the reader's)."""
        self.metrics.stream_frames.labels("refused" if seq is not None else "bad_message").inc()
        error = {"type": "error", "seq": seq, "status": status, "detail": detail}
        await (self.send(error) if seq is not None else self.owe(error))

    async def owe(self, notice: dict[str, Any]) -> None:
        """Queue a notice for the notifier; a client owed ``NOTICES_OWED`` already is not reading them."""
        try:
            self.notices.put_nowait(notice)
        except asyncio.QueueFull:
            raise NotReading(
                f"not reading: {NOTICES_OWED} answers to its text messages are waiting to be taken"
            ) from None

    async def notify(self) -> None:
        """Send what the reader owes, in order, for as long as the stream is open."""
        while True:
            await self.send(await self.notices.get())

    async def read(self) -> str:
        """Read until the client leaves or idles; returns why the stream ends."""
        seq = 0
        while True:
            try:
                message = await asyncio.wait_for(self.socket.receive(), self.settings.stream_idle_s)
            except TimeoutError:
                return "idle"
            if message["type"] == "websocket.disconnect":
                return "left"
            if message.get("bytes") is not None:
                seq += 1
                self.metrics.stream_frames.labels("received").inc()
                if self.mailbox.put(Frame(seq, message["bytes"], time.perf_counter())):
                    self.metrics.stream_frames.labels("skipped").inc()
            elif message.get("text") is not None:
                await self.change(message["text"])

    async def change(self, text: str) -> None:
        """A JSON object of options: merged into the stream's, checked, and acknowledged with the result."""
        try:
            change = json.loads(text)
        except (ValueError, RecursionError) as e:  # malformed, a number too long to convert, nested too deep
            await self.refuse(400, f"a text message must be a JSON object of options: {str(e)[:200]}")
            return
        if not isinstance(change, dict):
            await self.refuse(400, f"a text message must be a JSON object of options, not {type(change).__name__}")
            return
        try:
            options = parse_options(self.options.model_dump(exclude_unset=True) | change)
            self.model, self.request = await resolve(self.catalog, options, self.settings)
        except OptionsError as e:
            await self.refuse(e.status, e.message)
            return
        self.options = options
        self.smoother = self._smoother()  # another model or camera: what came before is no guide
        await self.owe({"type": "options", "options": options.model_dump(exclude_unset=True)})

    async def answer(self) -> None:
        """Answer the waiting frame, one at a time, for as long as the stream is open."""
        while True:
            frame = await self.mailbox.take()
            model, options = self.model, self.options
            started = time.perf_counter()
            limit = self.settings.stream_max_frame_bytes
            if len(frame.data) > limit:  # answered here, in order with the frames before it
                await self.refuse(413, f"the frame is {len(frame.data)} bytes; the limit is {limit}", frame.seq)
                continue
            try:
                result: StreamFrame = await self.pool.run(
                    stream_frame, model, frame.data, self.request, options.camera(), options.frame(), self.smoother
                )
            except BadImage as e:
                await self.refuse(e.status, e.message, frame.seq)
                continue
            except Overloaded:
                await self.refuse(503, "busy: the inference queue is full; the next frame may get in", frame.seq)
                continue
            self.metrics.inference.labels(model.label).observe(result.stages["inference"])
            await self.send(self.header(frame, result, started), [body for _, _, body in result.payloads])
            self.metrics.stream_frames.labels("answered").inc()

    def header(self, frame: Frame, result: StreamFrame, started: float) -> dict[str, Any]:
        k = result.camera.intrinsics
        height, width = k.height, k.width
        payloads = []
        for kind, encoding, body in result.payloads:
            entry: dict[str, Any] = {"kind": kind, "encoding": encoding, "bytes": len(body)}
            entry |= {"width": width, "height": height} if kind == "depth" else {"points": result.points}
            payloads.append(entry)
        headers = result.headers
        return {
            "type": "frame",
            "seq": frame.seq,
            "skipped": self.mailbox.skipped,
            "model": headers["X-Model-Name"],
            "version": headers["X-Model-Version"],
            "precision": headers["X-Precision"],
            "engine": headers["X-Engine"],
            "precision_fallback": headers.get("X-Precision-Fallback"),
            "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": width, "height": height},
            "intrinsics_source": result.camera.source,
            "focal_ratio": float(headers["X-Focal-Ratio"]),
            "queued_ms": round((started - frame.received) * 1000, 2),
            "stages_ms": {name: round(seconds * 1000, 2) for name, seconds in result.stages.items()},
            "payloads": payloads,
        }

    async def run(self) -> None:
        tasks = [asyncio.create_task(c) for c in (self.read(), self.answer(), self.notify())]
        reader = tasks[0]
        done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        failed = next((t for t in tasks if t in done and not t.cancelled() and t.exception() is not None), None)
        if failed is not None and isinstance(failed.exception(), WebSocketDisconnect | OSError):
            return  # the client left while an answer was being read or sent
        if failed is not None and isinstance(failed.exception(), NotReading):
            self.metrics.streams_refused.labels("not_reading").inc()
            log.warning("closed a stream: %s", failed.exception())
            with contextlib.suppress(WebSocketDisconnect, OSError, RuntimeError):
                await asyncio.wait_for(self.socket.close(POLICY, str(failed.exception())[:120]), 5)
            return
        if failed is not None:
            log.error("stream failed", exc_info=failed.exception())
            await self.socket.close(SERVER_ERROR, "the service failed on this stream; it is logged")
        elif reader in done and reader.result() == "idle":
            await self.socket.close(GOING_AWAY, f"idle: no message for {self.settings.stream_idle_s:g} s")


@router.websocket("/v1/stream")
async def stream(socket: WebSocket) -> None:
    """Frames in as binary messages, a JSON header and the payloads it lists out for each (docs/api.md)."""
    state = socket.app.state
    settings: Settings = state.settings
    if not origin_allowed(socket.headers.get("origin"), socket.headers.get("host"), settings.cors_origins):
        state.metrics.streams_refused.labels("origin").inc()
        await socket.close(POLICY, "this origin may not open a stream (RGB2CLOUD_CORS_ORIGINS)")
        return  # closed before accepting: the browser's handshake fails with 403
    streams: OpenStreams = state.streams
    await socket.accept()
    if not streams.try_open():
        with contextlib.suppress(WebSocketDisconnect, OSError):  # a client that left at once
            await socket.close(TRY_AGAIN_LATER, f"busy: {streams.limit} streams are open, the most this service takes")
        state.metrics.streams_refused.labels("full").inc()
        return
    try:
        try:
            options = parse_options(dict(socket.query_params))
            model, request = await resolve(state.catalog, options, settings)
        except OptionsError as e:
            await socket.send_text(json.dumps({"type": "error", "seq": None, "status": e.status, "detail": e.message}))
            await socket.close(POLICY, e.message[:120])
            return
        await Stream(socket, options, model, request).run()
    except WebSocketDisconnect:
        pass
    finally:
        streams.close()
