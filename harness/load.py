"""A bounded load of ``POST /depth`` from client threads, counting what came back: for the fault tests.

A balancer's faults (a replica killed, stopped or replaced mid-load) are judged by what the clients got:
how many requests succeeded, with which status each failed, which model version answered, and, where a
replica is killed, how many answers were cut off on their way out and sent again.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

import httpx


class Load:
    """At least ``count`` POST /depth through the balancer from ``clients`` threads; what each got back.

    With ``until``, the clients keep sending until that event is set too: a fault that takes longer than
    ``count`` requests (a rolling update on a fast CPU) is then always met by load, start to end.
    With ``resend_cut``, a request whose answer is cut off (the connection closes before the whole answer
    came: a replica killed while its answer was on its way out, which the balancer has committed to once
    it has the answer's header) is sent again once, as ``rgb2cloud client`` does, and counted in ``cut``;
    without it, that is a failure like any other.
    """

    def __init__(
        self,
        url: str,
        count: int,
        clients: int,
        photo: bytes,
        params: dict | None = None,
        until: threading.Event | None = None,
        resend_cut: bool = False,
    ):
        self.url, self.count, self.clients, self.photo, self.params = url, count, clients, photo, params
        self.until, self.resend_cut = until, resend_cut
        self.statuses: Counter[str] = Counter()
        self.versions: Counter[str] = Counter()
        self.latencies: list[float] = []
        self.done = 0
        #: Answers cut off on their way out and sent again (``resend_cut``).
        self.cut = 0
        self._sent = 0
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run)

    def start(self) -> Load:
        self._thread.start()
        return self

    def wait(self, timeout_s: float = 300) -> Load:
        self._thread.join(timeout_s)
        assert not self._thread.is_alive(), f"the load did not finish in time: {self.done} done, {self.statuses}"
        return self

    def wait_for(self, done: int) -> None:
        while self.done < done and self._thread.is_alive():
            time.sleep(0.02)

    def _one(self, client: httpx.Client) -> None:
        start = time.perf_counter()
        for attempt in range(2):
            try:
                r = client.post("/depth", files={"image": ("p.png", self.photo)}, params=self.params)
                status, version = str(r.status_code), r.headers.get("x-model-version", "")
            except httpx.RemoteProtocolError as e:
                status, version = type(e).__name__, ""
                if attempt == 0 and self.resend_cut:
                    with self._lock:
                        self.cut += 1
                    continue
            except httpx.HTTPError as e:
                status, version = type(e).__name__, ""
            break
        with self._lock:
            self.statuses[status] += 1
            self.versions[version] += 1
            self.latencies.append(time.perf_counter() - start)
            self.done += 1

    def _next(self) -> bool:
        """Whether a client sends one more request: until ``count`` are sent and ``until`` (if any) is set."""
        with self._lock:
            more = self._sent < self.count or (self.until is not None and not self.until.is_set())
            self._sent += more
            return more

    def _client(self, client: httpx.Client) -> None:
        while self._next():
            self._one(client)

    def _run(self) -> None:
        with httpx.Client(base_url=self.url, timeout=60) as client, ThreadPoolExecutor(self.clients) as pool:
            list(pool.map(lambda _: self._client(client), range(self.clients)))

    @property
    def failed(self) -> int:
        return self.done - self.statuses["200"]
