"""The client side of ``/v1/stream``: open a stream, send frames, read answers, unpack their payloads.

Written against the protocol as docs/api.md states it, with the ``websockets`` library and nothing of
the service's own code, so what the tests and benchmarks check through it is what any client receives.
``answers`` drives a whole source through one stream, for ``rgb2cloud stream``.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, TypeVar
from urllib.parse import urlencode

import numpy as np
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

T = TypeVar("T")
#: How long one payload of an answer may take to arrive once its header has: a full-resolution cloud is
#: 4.6 MB, seconds on a slow link.
PAYLOAD_TIMEOUT_S = 120


def stream_url(service_url: str, **options: Any) -> str:
    """``ws://host:port/v1/stream?...`` for a service's ``http://`` URL and the stream's options."""
    query = urlencode({k: v for k, v in options.items() if v is not None})
    return service_url.replace("http://", "ws://", 1) + "/v1/stream" + (f"?{query}" if query else "")


def open_stream(service_url: str, origin: str | None = None, **options: Any) -> ClientConnection:
    """A stream, with no compression (as browsers' frames are JPEG anyway) and no message size limit."""
    headers = {"Origin": origin} if origin else None
    return connect(
        stream_url(service_url, **options), max_size=None, compression=None, additional_headers=headers, open_timeout=30
    )


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
    """One frame's answer: the item it was sent for, the header, and the payloads by kind."""

    item: T
    header: dict[str, Any]
    payloads: dict[str, bytes]

    @property
    def error(self) -> str | None:
        """The service's words for a frame it refused, else None."""
        if self.header["type"] != "error":
            return None
        return f"{self.header['status']}: {self.header['detail']}"


def answers(
    socket: ClientConnection,
    items: Iterable[T],
    encode: Callable[[T], bytes],
    live: bool,
    in_flight: int = 2,
) -> Iterator[Answer[T]]:
    """Send every item's frame through the stream and yield the answers in order.

    A file source (``live`` False) keeps at most ``in_flight`` frames unanswered, so every frame is
    answered; two is what the service holds (one worked on, one waiting). A live source sends each
    frame as it comes and the service answers the freshest, so frames it skipped get no answer: an
    answer stands for every frame sent before it. A sender thread feeds a live stream while answers
    are read here; stopping the generator (Ctrl-C) closes the stream.
    """
    sent: dict[int, T] = {}  # the frames not answered yet, by number: each is dropped once answered
    count, ended = [0], threading.Event()  # how many were sent; set once the source has no more
    done = threading.Event()
    window = threading.Semaphore(in_flight)
    failure: list[BaseException] = []

    def send_all() -> None:
        try:
            for seq, item in enumerate(items, 1):
                if done.is_set():
                    return
                if not live:
                    window.acquire()
                data = encode(item)
                sent[seq] = item
                socket.send(data)
                count[0] = seq
        except ConnectionClosed:
            return
        except BaseException as e:  # a source that fails mid-way: reported where answers are read
            failure.append(e)
        finally:
            ended.set()

    sender = threading.Thread(target=send_all, daemon=True)
    sender.start()
    last = 0
    try:
        while not (ended.is_set() and last >= count[0]):
            try:  # only the wait for a header is short: an answer's payloads may take long on a slow link
                text = socket.recv(timeout=0.5)
            except TimeoutError:
                continue
            header = json.loads(text)
            bodies = [socket.recv(timeout=PAYLOAD_TIMEOUT_S) for _ in header.get("payloads", [])]
            seq = header.get("seq")
            if seq is None:
                raise StreamRefused(f"the service refused the stream's options: {header.get('detail')}")
            item = sent.pop(seq)
            for earlier in range(last + 1, seq):  # skipped by the service: they get no answer
                sent.pop(earlier, None)
            last = seq
            window.release()
            kinds = {entry["kind"]: body for entry, body in zip(header.get("payloads", []), bodies, strict=True)}
            yield Answer(item, header, kinds)
        if failure:
            raise failure[0]
    finally:
        done.set()
        window.release()
        sender.join(timeout=5)
