"""The client side of ``/v1/stream``: open a stream, send frames, read answers, unpack their payloads.

Written against the protocol as docs/api.md states it, with the ``websockets`` library and nothing of
the service's own code, so what the tests and benchmarks check through it is what any client receives.
``answers`` drives a whole source through one stream, for ``rgb2cloud stream``.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, TypeVar
from urllib.parse import urlencode

import numpy as np
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from contract.encodings import MESSAGE_BYTES_PER_PIXEL, STREAM_MAX_PIXELS

T = TypeVar("T")
#: How long one payload of an answer may take to arrive once its header has: a full-resolution cloud is
#: 4.6 MB, seconds on a slow link.
PAYLOAD_TIMEOUT_S = 120


def stream_url(service_url: str, **options: Any) -> str:
    """``ws://host:port/v1/stream?...`` for a service's ``http://`` URL and the stream's options."""
    query = urlencode({k: v for k, v in options.items() if v is not None})
    return service_url.replace("http://", "ws://", 1) + "/v1/stream" + (f"?{query}" if query else "")


def open_stream(
    service_url: str, origin: str | None = None, max_pixels: int = STREAM_MAX_PIXELS, **options: Any
) -> ClientConnection:
    """A stream, with no compression (as browsers' frames are JPEG anyway), that accepts messages as large as an
    answer to a photo of ``max_pixels`` can be and no larger: a wrong URL cannot fill the client's memory."""
    headers = {"Origin": origin} if origin else None
    url, limit = stream_url(service_url, **options), MESSAGE_BYTES_PER_PIXEL * max_pixels
    return connect(url, max_size=limit, compression=None, additional_headers=headers, open_timeout=30)


def receive(socket: ClientConnection, timeout: float | None = 120) -> tuple[dict[str, Any], list[bytes]]:
    """One answer: the JSON header, and the binary payloads it announces (none for an error or options)."""
    header = json.loads(socket.recv(timeout=timeout))
    payloads = [socket.recv(timeout=timeout) for _ in header.get("payloads", [])]
    assert all(isinstance(p, bytes) for p in payloads), "a payload arrived as text"
    return header, payloads


def raw_depth(entry: dict[str, Any], body: bytes) -> np.ndarray:
    """A ``raw32`` (float32 metres) or ``raw16`` (millimetres) depth payload as metres, height x width (0 where
    there is no depth)."""
    shape = entry["height"], entry["width"]
    if entry["encoding"] == "raw32":
        return np.frombuffer(body, dtype="<f4").reshape(shape)
    return np.frombuffer(body, dtype="<u2").reshape(shape).astype(np.float64) / 1000.0


def raw_points(entry: dict[str, Any], body: bytes) -> tuple[np.ndarray, np.ndarray]:
    """A ``raw`` point cloud payload as (N x 3 float32 x, y, z; N x 3 uint8 r, g, b)."""
    count = entry["points"]
    xyz = np.frombuffer(body, dtype="<f4", count=3 * count).reshape(count, 3)
    rgb = np.frombuffer(body, dtype=np.uint8, offset=12 * count).reshape(count, 3)
    return xyz, rgb


class StreamRefused(Exception):
    """The service refused the stream's options (its words), so no frame would be answered."""


@dataclass
class Answer(Generic[T]):
    """One frame's answer: the item it was sent for, the header, the payloads by kind, and how often the
    frame was sent (more than once after 503s)."""

    item: T
    header: dict[str, Any]
    payloads: dict[str, bytes]
    tries: int = 1

    @property
    def error(self) -> str | None:
        """The service's words for a frame it refused, else None."""
        if self.header["type"] != "error":
            return None
        return f"{self.header['status']}: {self.header['detail']}"


#: A file source's frame refused with 503 (the service's inference queue was full) is sent again this many
#: times, waiting 1, 2, 4, ... s (at most ``RETRY_WAIT_MAX_S``) before each, as ``rgb2cloud client`` retries a POST.
RETRIES, RETRY_WAIT_MAX_S = 5, 30.0


@dataclass
class Sent(Generic[T]):
    """A frame on its way: its place in the source, the item, and how often it was sent."""

    order: int
    item: T
    tries: int = 1


class Conversation(Generic[T]):
    """What ``answers`` shares between its sender thread and the reading loop: each binary message sent
    gets the next ``seq``, as the service counts them, under one lock whichever thread sends it."""

    def __init__(self, socket: ClientConnection, in_flight: int):
        self.socket, self.in_flight = socket, in_flight
        self.sent: dict[int, Sent[T]] = {}  # not answered yet, by seq: each is dropped once answered
        self.seq = 0
        self.lock = threading.Lock()
        self.window = threading.Semaphore(in_flight)
        self.ended, self.done = threading.Event(), threading.Event()
        self.failure: list[BaseException] = []
        self.options: dict[str, Any] | None = None

    def send(self, entry: Sent[T], data: bytes) -> None:
        with self.lock:
            self.seq += 1
            self.sent[self.seq] = entry
            self.socket.send(data)

    def change(self, options: dict[str, Any], drain: bool) -> None:
        """New options (a frame's camera); with ``drain``, once every frame sent before is answered, so none
        is answered with them. The service acknowledges them with a header the reading loop passes over."""
        slots = self.in_flight if drain else 0
        for _ in range(slots):
            self.window.acquire()
        with self.lock:  # never between another thread's frame and its seq
            self.socket.send(json.dumps(options))
        self.options = options
        for _ in range(slots):
            self.window.release()


def answers(
    socket: ClientConnection,
    items: Iterable[T],
    encode: Callable[[T], bytes],
    live: bool,
    in_flight: int = 2,
    options_of: Callable[[T], dict[str, Any] | None] | None = None,
) -> Iterator[Answer[T]]:
    """Send every item's frame through the stream and yield the answers in the source's order.

    A file source (``live`` False) keeps at most ``in_flight`` frames unanswered, so every frame is
    answered; two is what the service holds (one worked on, one waiting). The caller opens the stream
    with the first item's options (``options_of``: its camera); a later item's that differ are sent
    before it, once the frames before it are answered. A frame refused with 503 is sent again
    (``RETRIES``). A live source sends each frame as it comes and the service answers the freshest, so
    frames it skipped get no answer: an answer stands for every frame sent before it. A sender thread
    feeds the stream while answers are read here; stopping the generator (Ctrl-C) closes the stream.
    """
    talk: Conversation[T] = Conversation(socket, in_flight)

    def send_all() -> None:
        try:
            for order, item in enumerate(items):
                if talk.done.is_set():
                    return
                wanted = options_of(item) if options_of is not None else None
                if order == 0:
                    talk.options = wanted  # the caller opened the stream with the first item's options
                elif wanted is not None and wanted != talk.options:
                    talk.change(wanted, drain=not live)
                if not live:
                    talk.window.acquire()
                talk.send(Sent(order, item), encode(item))
        except ConnectionClosed:
            return
        except BaseException as e:  # a source that fails mid-way: reported where answers are read
            talk.failure.append(e)
        finally:
            talk.ended.set()

    sender = threading.Thread(target=send_all, daemon=True)
    sender.start()
    try:
        yield from _read_answers(talk, encode, live)
        if talk.failure:
            raise talk.failure[0]
    finally:
        talk.done.set()
        for _ in range(in_flight):  # a sender waiting for the window, or draining it, goes on to see done
            talk.window.release()
        sender.join(timeout=5)


def _read_answers(talk: Conversation[T], encode: Callable[[T], bytes], live: bool) -> Iterator[Answer[T]]:
    """The reading half of ``answers``: each answer, in the source's order, 503s sent again first."""
    ready: dict[int, Answer[T]] = {}
    next_order, last = 0, 0
    while not (talk.ended.is_set() and not talk.sent and not ready):
        try:  # only the wait for a header is short: an answer's payloads may take long on a slow link
            text = talk.socket.recv(timeout=0.5)
        except TimeoutError:
            continue
        header = json.loads(text)
        bodies = [talk.socket.recv(timeout=PAYLOAD_TIMEOUT_S) for _ in header.get("payloads", [])]
        if header.get("type") == "options":
            continue  # the acknowledgement of options sent between frames
        seq = header.get("seq")
        if seq is None:
            raise StreamRefused(f"the service refused the stream's options: {header.get('detail')}")
        with talk.lock:
            entry = talk.sent.pop(seq)
            skipped = [talk.sent.pop(s) for s in range(last + 1, seq) if s in talk.sent]  # they get no answer
        last = seq
        if not live:  # within the window the service skips none; if it ever did, the order must go on
            for lost in skipped:
                talk.window.release()
                lost_header = {"type": "error", "seq": None, "status": "skipped", "detail": "a newer frame replaced it"}
                ready[lost.order] = Answer(lost.item, lost_header, {})
        if not live and header.get("status") == 503 and entry.tries <= RETRIES:
            # It keeps its place in the window: sent again, not released.
            time.sleep(min(2.0 ** (entry.tries - 1), RETRY_WAIT_MAX_S))
            talk.send(Sent(entry.order, entry.item, entry.tries + 1), encode(entry.item))
            continue
        talk.window.release()
        kinds = {e["kind"]: body for e, body in zip(header.get("payloads", []), bodies, strict=True)}
        answer = Answer(entry.item, header, kinds, entry.tries)
        if live:
            yield answer
            continue
        ready[entry.order] = answer
        while next_order in ready:
            yield ready.pop(next_order)
            next_order += 1
