"""The service as a child process (``python -m app`` under uvicorn) on a free loopback port, and what is read off it.

For whatever needs a real server to talk to over HTTP: the test suite, the serving
benchmark, a local replica. It waits for ``/readyz``, so the caller starts on a
verified, warmed model, and stops the process however the block is left.
"""

from __future__ import annotations

import io
import os
import socket
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
from PIL import Image

from contract.geometry import Intrinsics

#: The folder the child starts in, so a relative RGB2CLOUD_REGISTRY means what it does for ``make serve``.
REPO = Path(__file__).resolve().parents[1]
#: A registry that does not exist. A child serves only the registries its caller names (``registry=``,
#: ``bundled_registry=``): no test or benchmark reads a user's models or the checkout's weights by accident.
NO_REGISTRY = Path(tempfile.gettempdir()) / "rgb2cloud-no-registry"
#: The checkout's bundled registry, for ``bundled_registry=``.
BUNDLED_REGISTRY = str(REPO / "weights")


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def resident_mb(pid: int) -> float:
    """A process's resident memory in MB (Linux ``/proc``): what the soak test and the benchmark watch."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise ValueError(f"/proc/{pid}/status has no VmRSS line")


@dataclass(frozen=True)
class Service:
    """A started service: where to reach it, and its process id (to measure or signal it)."""

    url: str
    pid: int


class ServiceProcess:
    """One ``python -m app`` child on a loopback port: started, waited for, signalled, stopped."""

    def __init__(self, port: int | None = None, **env: str):
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        environment = {
            **os.environ,
            "RGB2CLOUD_PORT": str(self.port),
            "RGB2CLOUD_HOST": "127.0.0.1",
            "RGB2CLOUD_REGISTRY": str(NO_REGISTRY),
            "RGB2CLOUD_BUNDLED_REGISTRY": str(NO_REGISTRY),
            **{f"RGB2CLOUD_{k.upper()}": v for k, v in env.items()},
        }
        # Its log goes to a file, not a pipe: a pipe nobody drains fills up after a few hundred
        # access-log lines and then blocks the service mid-request.
        self.log_file = tempfile.NamedTemporaryFile(prefix=f"rgb2cloud-{self.port}-", suffix=".log", delete=False)  # noqa: SIM115 (closed by stop)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "app"], cwd=REPO, env=environment, stdout=self.log_file, stderr=subprocess.STDOUT
        )

    @property
    def pid(self) -> int:
        return self.process.pid

    def log(self) -> str:
        """Everything the service has printed so far."""
        return Path(self.log_file.name).read_text(errors="replace")

    def wait_ready(self, timeout_s: float = 60) -> ServiceProcess:
        """Block until ``/readyz`` says ready; a RuntimeError with the log if it exits or takes too long."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self.process.poll() is not None:
                raise RuntimeError(f"service exited with {self.process.returncode}:\n{self.log()}")
            try:
                if httpx.get(f"{self.url}/readyz", timeout=1).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError(f"service did not become ready in {timeout_s:.0f} s")
            time.sleep(0.2)

    def stop(self, timeout_s: float = 30) -> int:
        """SIGTERM (uvicorn finishes what it has in flight, then exits), SIGKILL after ``timeout_s``."""
        self.process.terminate()
        try:
            return self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            return self.process.wait()
        finally:
            self.log_file.close()


@contextmanager
def running_service(**env: str):
    """Yield a started service (URL and PID); the settings come in as RGB2CLOUD_* variables."""
    service = ServiceProcess(**env)
    try:
        service.wait_ready()
        yield Service(service.url, service.pid)
    finally:
        service.stop(timeout_s=10)


def served_depths(model: str, photos: list[Path]) -> list[np.ndarray]:
    """``/depth`` (metres) of each photo file from a service started for the bundled ``model`` (``name:version``)."""
    depths = []
    with running_service(bundled_registry=BUNDLED_REGISTRY, model=model) as service:
        for photo in photos:
            response = httpx.post(
                f"{service.url}/depth", files={"image": (photo.name, photo.read_bytes())}, timeout=120
            )
            response.raise_for_status()
            depths.append(np.asarray(Image.open(io.BytesIO(response.content)), dtype=np.float64) / 1000)
    return depths


def server_timing(response: httpx.Response) -> dict[str, float]:
    """The service's ``Server-Timing`` header as {stage: ms}, in the order the stages ran."""
    stages = {}
    for entry in response.headers["server-timing"].split(","):
        name, duration = entry.strip().split(";dur=")
        stages[name] = float(duration)
    return stages


class ServedDepth:
    """The service's ``/depth`` as a predictor: a photo (lossless PNG) and its camera in, metres out.

    It has the shape of the trainer's frame predictors (``predict(rgb, intrinsics)``), so a service is
    scored by the same code that scores a model in process (``trainer.evaluate.evaluate_frames``). The
    depth PNG is millimetres: a served score differs from an in-process one by that rounding alone.
    ``focal_ratios`` collects the ``X-Focal-Ratio`` values seen.
    """

    def __init__(self, url: str, model: str):
        self.url, self.model = url, model
        self.focal_ratios: set[str] = set()

    def __call__(self, rgb: np.ndarray, camera: Intrinsics) -> np.ndarray:
        photo = io.BytesIO()
        Image.fromarray(rgb).save(photo, format="PNG")
        params = {"model": self.model, "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy}
        r = httpx.post(f"{self.url}/depth", files={"image": photo.getvalue()}, params=params, timeout=120)
        r.raise_for_status()
        self.focal_ratios.add(r.headers["x-focal-ratio"])
        with Image.open(io.BytesIO(r.content)) as im:
            return np.asarray(im, dtype=np.float32) / 1000.0
