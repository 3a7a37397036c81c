"""The service as a child process (``python -m app`` under uvicorn) on a free loopback port.

For whatever needs a real server to talk to over HTTP: the test suite, the serving
benchmark, a local replica. It waits for ``/readyz``, so the caller starts on a
verified, warmed model, and stops the process however the block is left.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx

#: The folder the child starts in, so a relative RGB2CLOUD_REGISTRY means what it does for ``make serve``.
REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass(frozen=True)
class Service:
    """A started service: where to reach it, and its process id (to measure or signal it)."""

    url: str
    pid: int


@contextmanager
def running_service(**env: str):
    """Yield a started service (URL and PID); the settings come in as RGB2CLOUD_* variables."""
    port = free_port()
    environment = {
        **os.environ,
        "RGB2CLOUD_PORT": str(port),
        "RGB2CLOUD_HOST": "127.0.0.1",
        **{f"RGB2CLOUD_{k.upper()}": v for k, v in env.items()},
    }
    process = subprocess.Popen(
        [sys.executable, "-m", "app"],
        cwd=REPO,
        env=environment,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            if process.poll() is not None:
                raise RuntimeError(f"service exited with {process.returncode}:\n{process.stdout.read()}")
            try:
                if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("service did not become ready in 60 s")
            time.sleep(0.2)
        yield Service(url, process.pid)
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
