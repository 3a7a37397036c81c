"""Replicas behind the real load balancer, as processes: faults survived, nothing lost.

The topology of ``deploy/compose.yaml`` without a container engine: three replicas under
uvicorn on loopback ports and Debian's nginx running ``deploy/nginx/nginx.conf`` as shipped
(only its listening port, log and temp paths, and the upstream list change). A bounded load
(request count and time) runs against the balancer while a replica is SIGKILLed, SIGTERMed,
or every replica is replaced by a new model version; then beyond capacity; then a soak.
Each scenario's requests sent, succeeded, retried (by the balancer), cut off on their way out and sent
again (by the client, only where a replica is killed) and failed are written to
``runs/test-artifacts/scale-out.md``.
"""

from __future__ import annotations

import io
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import httpx
import pytest
from conftest import REPO, TUM_FRAME, run_cli
from PIL import Image
from websockets.exceptions import InvalidStatus

from clients.stream import open_stream, receive
from contract.card import load_card, publish
from harness.load import Load
from harness.service import ServiceProcess, free_port, resident_mb

#: Real processes, networks or browsers: the full suite (`make test`) runs these, `-m 'not slow'` skips them.
pytestmark = pytest.mark.slow

NGINX = shutil.which("nginx") or "/usr/sbin/nginx"
REPORT = REPO / "runs" / "test-artifacts" / "scale-out.md"
PHOTO = (TUM_FRAME / "TUM_color.png").read_bytes()
REPLICA = {"threads": "1", "workers": "2", "max_queue": "2", "model": "tiny"}


class Balancer:
    """nginx with the shipped configuration, in front of ``ports``, logging who answered each request."""

    def __init__(self, folder: Path, ports: list[int]):
        self.folder, self.port = folder, free_port()
        config = (REPO / "deploy" / "nginx" / "nginx.conf").read_text()
        assert "listen 8080;" in config
        config = config.replace("listen 8080;", f"listen 127.0.0.1:{self.port};").replace("/tmp/", f"{folder}/")
        (folder / "nginx.conf").write_text(config)
        servers = "".join(f"    server 127.0.0.1:{p} max_fails=0;\n" for p in ports)  # as upstream.compose.conf
        (folder / "upstream.conf").write_text(f"upstream rgb2cloud {{\n{servers}    keepalive 32;\n}}\n")
        self.log = folder / "rgb2cloud-nginx-access.log"
        self.stderr = folder / "nginx-stderr.log"  # a file, not a pipe nobody drains
        with open(self.stderr, "w") as out:
            self.process = subprocess.Popen(
                [NGINX, "-p", str(folder), "-c", str(folder / "nginx.conf"), "-g", "daemon off;"], stderr=out
            )
        self.url = f"http://127.0.0.1:{self.port}"
        deadline = time.monotonic() + 20
        while True:
            try:
                httpx.get(f"{self.url}/healthz", timeout=1)
                break
            except httpx.TransportError:
                if self.process.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"nginx did not start: {self.stderr.read_text()}") from None
                time.sleep(0.1)

    def retried_since(self, line: int) -> int:
        """Requests since log line ``line`` that the balancer sent to more than one replica."""
        return sum("," in entry.split()[1] for entry in self.log.read_text().splitlines()[line:] if entry)

    def lines(self) -> int:
        return len(self.log.read_text().splitlines()) if self.log.exists() else 0

    def stop(self) -> None:
        self.process.terminate()
        self.process.wait(timeout=10)


@pytest.fixture(scope="module")
def registry(registry, tmp_path_factory):
    """A registry of its own: the tiny model, to which the rolling update publishes 0.2.0."""
    target = tmp_path_factory.mktemp("scale-registry") / "weights"
    shutil.copytree(registry, target)
    return target


@pytest.fixture(scope="module")
def cluster(registry, tmp_path_factory):
    if not Path(NGINX).is_file():
        pytest.fail("no nginx: `make test` installs Debian's package (apt-get install nginx-light)")
    replicas = [ServiceProcess(registry=str(registry), **REPLICA) for _ in range(3)]
    for replica in replicas:
        replica.wait_ready()
    balancer = Balancer(tmp_path_factory.mktemp("nginx"), [r.port for r in replicas])
    REPORT.parent.mkdir(parents=True, exist_ok=True)
    REPORT.write_text(
        "| scenario | requests sent | succeeded | retried by the balancer | cut off, sent again by the client "
        "| failed |\n|---|---|---|---|---|---|\n"
    )
    yield replicas, balancer
    balancer.stop()
    for replica in replicas:
        replica.stop(timeout_s=10)


def report(scenario: str, load: Load, retried: int) -> None:
    cut = load.cut if load.resend_cut else "—"  # elsewhere an answer cut off is a failure
    row = f"| {scenario} | {load.done} | {load.statuses['200']} | {retried} | {cut} | {load.failed} |"
    print(row, dict(load.statuses))
    with REPORT.open("a") as f:
        f.write(row + "\n")


def drained(replica: ServiceProcess) -> bool:
    """uvicorn's graceful shutdown ran to its end: it stopped accepting, finished its requests, and exited.

    uvicorn re-raises the SIGTERM it handled once it is done, so the exit status is -15 or 0."""
    return replica.process.returncode in (0, -signal.SIGTERM) and "Finished server process" in replica.log()


def replace(replicas: list[ServiceProcess], index: int, registry: Path, **env: str) -> None:
    """Start a replica again on the same port, and wait until it is ready."""
    replicas[index] = ServiceProcess(replicas[index].port, registry=str(registry), **{**REPLICA, **env}).wait_ready()


def test_a_stream_opens_through_the_balancer_from_its_own_page(cluster):
    """The WebSocket upgrade passes nginx, and the page the balancer serves is the stream's own origin."""
    _, balancer = cluster
    photo = (TUM_FRAME / "TUM_color.png").read_bytes()
    with open_stream(balancer.url, origin=balancer.url, depth_encoding="raw16") as ws:
        for _ in range(3):
            ws.send(photo)
            header, (body,) = receive(ws)
            assert header["type"] == "frame" and len(body) == 2 * 640 * 480
    with pytest.raises(InvalidStatus) as refused:
        open_stream(balancer.url, origin="https://evil.example")
    assert refused.value.response.status_code == 403


def test_a_replica_killed_mid_load_loses_no_request(cluster, registry):
    replicas, balancer = cluster
    mark = balancer.lines()
    load = Load(balancer.url, 150, 6, PHOTO, resend_cut=True).start()
    load.wait_for(40)
    replicas[0].process.send_signal(signal.SIGKILL)
    load.wait()
    report("a replica killed with SIGKILL mid-load", load, balancer.retried_since(mark))
    assert load.failed == 0, load.statuses
    assert load.cut <= int(REPLICA["workers"])  # at most the answers the victim's workers were sending
    replicas[0].process.wait(timeout=10)
    replace(replicas, 0, registry)


def test_a_replica_stopped_with_sigterm_drains_and_loses_no_request(cluster, registry):
    replicas, balancer = cluster
    mark = balancer.lines()
    load = Load(balancer.url, 150, 6, PHOTO).start()
    load.wait_for(40)
    stopping = replicas[1]
    stopping.process.send_signal(signal.SIGTERM)
    stopping.process.wait(timeout=30)
    assert drained(stopping)
    with pytest.raises(httpx.TransportError):
        httpx.get(f"{stopping.url}/healthz", timeout=2)  # and takes nothing new
    load.wait()
    report("a replica stopped with SIGTERM mid-load", load, balancer.retried_since(mark))
    assert load.failed == 0, load.statuses
    replace(replicas, 1, registry)


def test_a_rolling_update_to_a_new_version_under_load(cluster, registry):
    replicas, balancer = cluster
    folder = registry / "tiny" / "0.1.0"
    card = load_card(folder).model_copy(update={"version": "0.2.0"})
    publish(registry, card, {f: folder / f for f in card.files})
    mark = balancer.lines()
    # The load runs from before the first replica stops until after the last one is replaced, however long
    # replacing takes on this CPU, and then for 40 requests more (all of which the new version answers).
    updated = threading.Event()
    load = Load(balancer.url, 40, 6, PHOTO, until=updated).start()
    load.wait_for(20)
    for index in range(len(replicas)):
        replicas[index].stop()
        assert drained(replicas[index])
        replace(replicas, index, registry, model="tiny:0.2.0")
    load.wait_for(load.done + 40)
    updated.set()
    load.wait()
    report("a rolling update of every replica to a new version", load, balancer.retried_since(mark))
    assert load.failed == 0, load.statuses
    assert set(load.versions) <= {"0.1.0", "0.2.0"} and load.versions["0.2.0"] > 0, load.versions
    assert httpx.post(f"{balancer.url}/depth", files={"image": PHOTO}).headers["x-model-version"] == "0.2.0"


def test_beyond_capacity_clients_get_503_at_once_and_the_client_retries_complete_the_batch(cluster, registry, tmp_path):
    _, balancer = cluster
    big = Image.open(TUM_FRAME / "TUM_color.png").convert("RGB").resize((1280, 960))
    # 1280x960 at the model's own focal length: generator calls long enough to fill every queue.
    own_focal = {"fx": load_card(registry / "tiny" / "0.1.0").camera.fx}
    mark = balancer.lines()
    load = Load(balancer.url, 120, 40, _png(big), own_focal).start().wait()
    report("overload: 40 clients, capacity 12", load, balancer.retried_since(mark))
    assert set(load.statuses) <= {"200", "503"} and load.statuses["503"] > 0, load.statuses
    assert max(load.latencies) < 30  # refused at once, never left to time out

    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(30):
        big.save(photos / f"photo{i}.png")
    args = ["--url", balancer.url, "--concurrency", "30", "--retries", "30", "--fx", str(own_focal["fx"])]
    result = run_cli("client", str(photos), "-o", str(tmp_path / "out"), *args)
    assert result.stdout.count("wrote") == 30, result.stdout + result.stderr


def test_a_soak_keeps_every_replica_memory_flat(cluster):
    replicas, balancer = cluster
    small = Image.open(TUM_FRAME / "TUM_color.png").convert("RGB").resize((160, 120))
    photo = _png(small)
    Load(balancer.url, 300, 6, photo).start().wait(timeout_s=90)  # warm every replica's allocator
    before = [resident_mb(r.pid) for r in replicas]
    mark = balancer.lines()
    load = Load(balancer.url, 3000, 6, photo).start().wait(timeout_s=600)
    after = [resident_mb(r.pid) for r in replicas]
    report("a soak: 3000 requests", load, balancer.retried_since(mark))
    growth = [b - a for a, b in zip(before, after, strict=True)]
    with REPORT.open("a") as f:
        f.write(
            "\nResident memory per replica across the soak (MB): "
            + ", ".join(f"{a:.0f} → {b:.0f}" for a, b in zip(before, after, strict=True))
            + "\n"
        )
    assert load.failed == 0, load.statuses
    assert max(growth) < 25, growth  # flat: within 25 MB over 3000 requests


def _png(image: Image.Image) -> bytes:
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()
