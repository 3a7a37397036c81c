"""The serving image, built and run: ``podman build`` of the Dockerfile, ``podman run`` of what it built, and
the compose recipe brought up with ``podman-compose``.

The container is checked over real HTTP as the service tests check the service: the depth PNG decoded and
compared with the bundled model run on this machine, the PLY read by plyfile and put back on the pinhole
model. ``harness/containers.py`` says how this sandbox differs from a user's machine (storage, runtime,
and a stand-in for ``python:3.11-slim`` built from Debian's packages). What was measured (build time,
size by layer, time to ready) is written to ``runs/test-artifacts/image.md``.
"""

from __future__ import annotations

import io
import json
import re
import shutil
import time
from collections.abc import Iterator

import httpx
import numpy as np
import pytest
from conftest import REPO, TUM_FRAME
from PIL import Image
from plyfile import PlyData

from app.catalog import ModelCatalog
from app.loading import LoadedModel
from app.settings import Settings
from harness import containers
from harness.load import Load
from harness.service import NO_REGISTRY, free_port

#: Real processes, networks or browsers: the full suite (`make test`) runs these, `-m 'not slow'` skips them.
pytestmark = pytest.mark.slow

REPORT = REPO / "runs" / "test-artifacts" / "image.md"
PHOTO = TUM_FRAME / "TUM_color.png"
#: The service's user in the image (the Dockerfile's USER).
UID = "10001"


def report(line: str) -> None:
    """A line of what was measured, printed and kept in the report."""
    print(line)
    with REPORT.open("a") as f:
        f.write(line + "\n")


@pytest.fixture(scope="module")
def image() -> str:
    reason = containers.why_not()
    if reason is not None:
        pytest.skip(f"podman cannot run containers here: {reason}")
    base = containers.standin_base()
    seconds = containers.build(REPO, containers.IMAGE, base)
    REPORT.parent.mkdir(parents=True, exist_ok=True)
    REPORT.write_text(f"# The serving image\n\nBuilt from `{base}` in {seconds:.0f} s.\n\n| layer | MB |\n|---|---|\n")
    for step, size in containers.layers(containers.IMAGE):
        if size:
            report(f"| `{step.replace('/bin/sh -c ', '').replace('#(nop) ', '')[:90]}` | {size / 1e6:.1f} |")
    report(f"\nImage: {containers.image_bytes(containers.IMAGE) / 1e6:.0f} MB. The largest installed packages, MB:")
    sizes = "du -sm $(python -c 'import site; print(site.getsitepackages()[0])')/* | sort -n | tail -6"
    report(containers.podman("run", "--rm", containers.IMAGE, "sh", "-c", sizes).stdout)
    return containers.IMAGE


@pytest.fixture(scope="module")
def served(image: str) -> Iterator[containers.Container]:
    """The image as users run it: no options but the published port."""
    with containers.running(image) as container:
        report(f"Ready {container.ready_s:.1f} s after `podman run`.")
        yield container


@pytest.fixture(scope="module")
def bundled() -> LoadedModel:
    """The bundled default model on this machine, on ONNX Runtime: what the image must agree with."""
    settings = Settings(registry=NO_REGISTRY, bundled_registry=REPO / "weights", engine="onnxruntime", threads=2)
    return ModelCatalog(settings).load_default()


def test_the_image_serves_depth_that_the_bundled_model_agrees_with(served, bundled):
    assert httpx.get(f"{served.url}/readyz").json()["model"] == bundled.card.name
    (default,) = [m for m in httpx.get(f"{served.url}/v1/models").json()["models"] if m["name"] == bundled.card.name]
    measured = next(v for v in default["versions"] if v["version"] == bundled.card.version)["serving"]["measured_ms"]
    assert {"onnxruntime fp32", "openvino fp32"} <= set(measured)  # both engines load, with OpenVINO's plugins cut
    camera = bundled.card.camera
    rgb = np.asarray(Image.open(PHOTO).convert("RGB"))
    r = httpx.post(
        f"{served.url}/depth",
        files={"image": PHOTO.read_bytes()},
        params={"fx": camera.fx, "fy": camera.fy, "precision": "fp32"},
        timeout=60,
    )
    assert r.status_code == 200 and r.headers["content-type"] == "image/png", r.text
    with Image.open(io.BytesIO(r.content)) as png:
        assert png.mode == "I;16" and png.size == (rgb.shape[1], rgb.shape[0])
        served_mm = np.asarray(png).astype(np.int64)
    here_mm = np.round(bundled.predict_depth(rgb) * 1000).astype(np.int64)
    difference = np.abs(served_mm - here_mm)
    # fp32 on either engine: the same millimetres but where a value sits on a rounding edge (as test_engines).
    assert difference.max() <= 2 and (difference == 0).mean() > 0.99, (difference.max(), (difference == 0).mean())


def test_the_image_s_point_cloud_is_its_depth_back_projected(served):
    photo = PHOTO.read_bytes()
    camera = {"fx": 600.0, "fy": 610.0, "cx": 330.5, "cy": 235.25}  # a camera of the photo's own, given
    depth = httpx.post(f"{served.url}/depth", files={"image": photo}, params=camera, timeout=60)
    assert depth.status_code == 200, depth.text
    cloud = httpx.post(
        f"{served.url}/pointcloud", files={"image": photo}, params={**camera, "max_depth": 100}, timeout=60
    )
    assert cloud.status_code == 200 and cloud.headers["content-type"] == "application/octet-stream", cloud.text
    assert cloud.headers["x-intrinsics-source"] == "query"
    fx, fy, cx, cy = (float(v) for v in cloud.headers["x-intrinsics"].split(","))
    assert (fx, fy, cx, cy) == tuple(camera.values())
    with Image.open(io.BytesIO(depth.content)) as png:
        mm = np.asarray(png).astype(np.float64)
    vertex = PlyData.read(io.BytesIO(cloud.content))["vertex"]
    v, u = np.nonzero(mm > 0)  # row-major, as the service emits
    assert vertex.count == len(u) == int(cloud.headers["x-point-count"]) > 0
    z = np.asarray(vertex["z"], dtype=np.float64)
    np.testing.assert_allclose(z, mm[v, u] / 1000, atol=0.0005 + 1e-6)  # the PNG rounds to the millimetre
    np.testing.assert_allclose(vertex["x"], z * (u - cx) / fx, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(vertex["y"], z * (v - cy) / fy, rtol=1e-4, atol=1e-5)
    rgb = np.asarray(Image.open(PHOTO).convert("RGB"))
    np.testing.assert_array_equal(np.stack([vertex["red"], vertex["green"], vertex["blue"]], 1), rgb[v, u])


def test_the_healthcheck_passes_as_uid_10001_with_no_torch(image, served):
    config = json.loads(containers.podman("image", "inspect", image).stdout)[0]
    healthcheck = config.get("Healthcheck") or config["Config"].get("Healthcheck")
    assert healthcheck and healthcheck["Test"][0] == "CMD", config  # --format docker kept it
    check = containers.podman("healthcheck", "run", served.name, check=False)
    assert check.returncode == 0, check.stdout + check.stderr
    assert served.run("id", "-u").stdout.strip() == UID
    no_torch = served.run("python", "-c", "import importlib.util as u; print(u.find_spec('torch') is None)")
    assert no_torch.stdout.strip() == "True", no_torch.stdout + no_torch.stderr


def test_a_registry_mounted_at_models_serves_its_model(image, registry, tmp_path):
    mounted = tmp_path / "models"
    shutil.copytree(registry, mounted)
    for path in [mounted, *mounted.rglob("*")]:  # pytest's folders are 700: uid 10001 must read the registry
        path.chmod(0o755 if path.is_dir() else 0o644)
    with containers.running(image, "--volume", f"{mounted}:/models:ro", "--env", "RGB2CLOUD_MODEL=tiny") as c:
        assert httpx.get(f"{c.url}/readyz").json()["model"] == "tiny"
        r = httpx.post(f"{c.url}/depth", files={"image": PHOTO.read_bytes()}, timeout=60)
        assert r.status_code == 200 and r.headers["x-model-name"] == "tiny", r.text
        names = {m["name"] for m in httpx.get(f"{c.url}/v1/models").json()["models"]}
        assert {"tiny", "rgb2cloud-7scenes"} <= names  # the bundled models are served beside the mounted ones


def test_a_read_only_root_serves_with_a_tmpfs_at_tmp_and_refuses_to_start_without_one(image):
    """As compose and Kubernetes run it. Uploads over 1 MB are spooled to a temporary file, so with no writable
    folder at all the service says so at startup rather than refuse every large photo."""
    read_only = ("--read-only", "--read-only-tmpfs=false")  # Docker's --read-only: podman's mounts tmpfs itself
    name = f"rgb2cloud-test-no-tmp-{free_port()}"
    try:
        without = containers.podman("run", "--name", name, *read_only, image, check=False, timeout=120)
    finally:
        containers.podman("rm", "--force", "--time", "2", name, check=False)
    assert without.returncode == 1 and "mount a tmpfs at /tmp" in without.stdout + without.stderr, without
    large = io.BytesIO()
    Image.open(PHOTO).convert("RGB").resize((1920, 1440), Image.Resampling.BICUBIC).save(large, "PNG")
    assert large.tell() > 1_000_000  # past the parser's in-memory limit
    with containers.running(image, *read_only, "--tmpfs", "/tmp") as c:
        r = httpx.post(f"{c.url}/depth", files={"image": large.getvalue()}, timeout=60)
        assert r.status_code == 200, r.text
        with Image.open(io.BytesIO(r.content)) as png:
            assert png.size == (1920, 1440)
        assert c.run("touch", "/var/tmp/x").returncode != 0  # world-writable on a writable root


@pytest.fixture(scope="module")
def cluster(image: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, list[str]]]:
    """``deploy/compose.yaml`` as shipped, up with ``podman-compose``: three replicas behind nginx."""
    nginx = containers.nginx_image(containers.standin_base())
    override = tmp_path_factory.mktemp("compose") / "override.yaml"
    override.write_text(f"services:\n  rgb2cloud:\n    image: {image}\n  balancer:\n    image: {nginx}\n")
    port = free_port()
    containers.compose("down", "--timeout", "2", override=override, check=False)  # a run interrupted before
    started = time.perf_counter()
    try:
        containers.compose("up", "--detach", override=override, env={"RGB2CLOUD_BALANCER_PORT": str(port)})
        url = f"http://127.0.0.1:{port}"
        names = containers.replicas("rgb2cloud", 3)
        for name in names:  # podman 4.3 starts the balancer without waiting for healthy replicas
            containers.wait_healthy(name, started)
        report(f"\nCompose: three replicas and the balancer ready {time.perf_counter() - started:.0f} s after `up`.")
        yield url, names
    finally:
        containers.compose("down", "--timeout", "2", override=override, check=False)


def balancer_log() -> list[str]:
    """The balancer's access log: status, every replica tried (``a, b`` when retried), their statuses, time."""
    (balancer,) = containers.replicas("balancer", 1)
    return containers.podman("exec", balancer, "cat", "/tmp/rgb2cloud-nginx-access.log").stdout.splitlines()


def answered_by(line: str) -> str:
    """The replica that answered a logged request: the last address nginx tried."""
    return re.findall(r"\d+\.\d+\.\d+\.\d+:\d+", line)[-1]


def test_compose_spreads_requests_over_the_replicas(cluster):
    url, names = cluster
    mark = len(balancer_log())
    load = Load(url, 30, 3, PHOTO.read_bytes()).start().wait()
    assert load.failed == 0, load.statuses
    answered = {answered_by(line) for line in balancer_log()[mark:]}
    assert len(answered) == len(names), answered


@pytest.mark.parametrize(("how", "exit_codes"), [("stop", {0, 143}), ("kill", {137})])
def test_compose_loses_no_request_when_a_replica_goes(cluster, how: str, exit_codes: set[int]):
    """docs/deploy.md's fault table: a replica stopped (SIGTERM: it drains and exits cleanly) or killed
    (SIGKILL) mid-load costs the clients nothing while the others answer; a killed replica's answer cut off
    on its way out is sent again by the client, as `rgb2cloud client` does."""
    url, names = cluster
    victim = names[1] if how == "stop" else names[2]
    mark = len(balancer_log())
    victim_ip = containers.podman(
        "inspect", "--format", "{{range .NetworkSettings.Networks}}{{.IPAddress}}{{end}}", victim
    ).stdout.strip()
    load = Load(url, 90, 6, PHOTO.read_bytes(), resend_cut=how == "kill").start()
    try:
        load.wait_for(20)
        containers.podman(how, victim)
        load.wait()
        exit_code = int(containers.podman("inspect", "--format", "{{.State.ExitCode}}", victim).stdout)
    finally:
        containers.podman("start", victim, check=False)
        containers.wait_healthy(victim, time.perf_counter())
    report(
        f"Compose, `podman {how}` of a replica mid-load: {dict(load.statuses)} of {load.count}, "
        f"{load.cut} answers cut off and sent again by the client; exit {exit_code}."
    )
    assert load.failed == 0, load.statuses
    assert load.cut <= 2  # at most the answers the victim's two workers (deploy/compose.yaml) were sending
    assert exit_code in exit_codes  # a stop that overran its grace period would be SIGKILLed: 137
    assert any(answered_by(line).startswith(f"{victim_ip}:") for line in balancer_log()[mark:])  # it had a share
