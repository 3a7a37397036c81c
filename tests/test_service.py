"""The service over real HTTP: uvicorn on 127.0.0.1, httpx, PNG decoded, PLY parsed by plyfile."""

from __future__ import annotations

import asyncio
import io
import json
import os
import shutil
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import httpx
import numpy as np
import pytest
from conftest import REPO, TUM_FRAME
from PIL import Image
from plyfile import PlyData
from pydantic import ValidationError

from app.catalog import ModelCatalog
from app.settings import Settings
from harness.service import NO_REGISTRY, running_service, server_timing

ALLOWED_ORIGIN = "https://viewer.example"
LIMIT = 2_000_000


@pytest.fixture(scope="module")
def service(registry):
    """The service on ONNX Runtime, the reference: these tests hold its answers to ``model``'s depth to the
    millimetre, and under auto each load picks its own engine by timing (tests/test_engines.py checks that)."""
    with running_service(
        registry=str(registry),
        max_upload_bytes=str(LIMIT),
        threads="1",
        cors_origins=json.dumps([ALLOWED_ORIGIN]),
        engine="onnxruntime",
    ) as running:
        url = running.url
        yield url


@pytest.fixture(scope="module")
def model(registry):
    return ModelCatalog(
        Settings(registry=registry, bundled_registry=NO_REGISTRY, threads=1, engine="onnxruntime")
    ).load_default()


def own_focal(model) -> dict[str, float]:
    """Query parameters saying the photo has the model's focal length: the generator sees it as it is."""
    return {"fx": model.card.camera.fx, "fy": model.card.camera.fy}


def png_bytes(array: np.ndarray, **save) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, format="PNG", **save)
    return buffer.getvalue()


def encoded(image: Image.Image, fmt: str, **save) -> bytes:
    buffer = io.BytesIO()
    image.save(buffer, format=fmt, **save)
    return buffer.getvalue()


def tum_rgb(width: int | None = None, height: int | None = None) -> np.ndarray:
    rgb = np.asarray(Image.open(TUM_FRAME / "TUM_color.png").convert("RGB"))
    return rgb[:height, :width]


def post(url: str, route: str, data: bytes, params: dict | None = None, **kw) -> httpx.Response:
    return httpx.post(f"{url}{route}", files={"image": ("photo", data)}, params=params, timeout=60, **kw)


def assert_healthy(url: str) -> None:
    assert httpx.get(f"{url}/healthz", timeout=5).json() == {"status": "ok"}
    assert httpx.get(f"{url}/readyz", timeout=5).status_code == 200


def test_depth_png_is_16_bit_millimetres_at_the_input_size(service, model):
    rgb = tum_rgb(333, 251)  # not a multiple of the generator's grid
    r = post(service, "/depth", png_bytes(rgb), own_focal(model))
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert 0 < float(r.headers["x-inference-ms"]) < 60_000
    assert (r.headers["x-model-name"], r.headers["x-model-version"], r.headers["x-depth-units"]) == (
        "tiny",
        "0.1.0",
        "mm",
    )
    with Image.open(io.BytesIO(r.content)) as im:
        depth_mm = np.asarray(im)
    assert depth_mm.shape == (251, 333) and depth_mm.dtype == np.uint16
    expected = np.rint(model.predict_depth(rgb) * 1000)
    assert np.abs(depth_mm.astype(np.int64) - expected).max() <= 1
    assert depth_mm.min() >= 250 and depth_mm.max() <= 10000  # within the card's depth encoding


@pytest.mark.parametrize(
    ("route", "stages"),
    [
        ("/depth", ["decode", "resample", "inference", "resample_back", "encode"]),
        ("/pointcloud", ["decode", "resample", "inference", "resample_back", "backproject", "encode"]),
    ],
)
def test_server_timing_names_each_stage_in_order(service, route, stages):
    start = time.perf_counter()
    r = post(service, route, png_bytes(tum_rgb(96, 72)))
    elapsed_ms = (time.perf_counter() - start) * 1000
    timing = server_timing(r)
    assert list(timing) == stages
    assert all(ms >= 0 for ms in timing.values())
    assert timing["inference"] == float(r.headers["x-inference-ms"])
    assert sum(timing.values()) <= elapsed_ms


def test_exif_orientation_is_applied(service):
    image = Image.fromarray(tum_rgb(64, 48))
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 90 degrees clockwise for display
    r = post(service, "/depth", encoded(image, "JPEG", exif=exif))
    with Image.open(io.BytesIO(r.content)) as im:
        assert im.size == (48, 64)


def test_colormap_preview(service):
    r = post(service, "/depth", png_bytes(tum_rgb(160, 120)), {"format": "colormap"})
    with Image.open(io.BytesIO(r.content)) as im:
        assert im.mode == "RGB" and im.size == (160, 120)
    lo, hi = (float(v) for v in r.headers["x-depth-range-m"].split(","))
    assert 0 < lo <= hi


def test_pointcloud_follows_formula_5_point_by_point(service, model):
    rgb = tum_rgb(161, 121)
    fx, fy, cx, cy = model.card.camera.fx, model.card.camera.fy, 80.25, 60.75
    params = {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "min_depth": 0.5, "max_depth": 3.0}
    r = post(service, "/pointcloud", png_bytes(rgb), params)
    assert r.status_code == 200
    ply = PlyData.read(io.BytesIO(r.content))
    assert ply.text is False and ply.byte_order == "<"
    vertex = ply["vertex"]
    assert [p.name for p in vertex.properties] == ["x", "y", "z", "red", "green", "blue"]
    assert int(r.headers["x-point-count"]) == vertex.count

    depth = model.predict_depth(rgb)
    v, u = np.nonzero((depth >= 0.5) & (depth <= 3.0))  # row-major, as the service emits
    assert vertex.count == len(u) > 0
    z = depth[v, u]
    np.testing.assert_allclose(vertex["z"], z, rtol=1e-4)
    np.testing.assert_allclose(vertex["x"], z * (u - cx) / fx, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(vertex["y"], z * (v - cy) / fy, rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(np.stack([vertex["red"], vertex["green"], vertex["blue"]], 1), rgb[v, u])


def test_pointcloud_defaults_to_the_card_camera_scaled_and_strides(service, model):
    r = post(service, "/pointcloud", png_bytes(tum_rgb(320, 240)), {"stride": 4})
    assert r.headers["x-intrinsics-source"] == "model"
    fx, fy, cx, cy = (float(x) for x in r.headers["x-intrinsics"].split(","))
    camera = model.card.camera  # the camera the model was trained at, its field of view across the photo
    scale = 320 / camera.width
    assert camera.width / camera.height == 320 / 240
    assert (fx, fy) == pytest.approx((camera.fx * scale, camera.fy * scale))
    assert (cx, cy) == pytest.approx(((camera.cx + 0.5) * scale - 0.5, (camera.cy + 0.5) * scale - 0.5))
    assert int(r.headers["x-point-count"]) == 80 * 60


def _png_claiming(width: int, height: int) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    )


def _truncated(fmt: str) -> bytes:
    data = encoded(Image.fromarray(tum_rgb(320, 240)), fmt)
    return data[: len(data) // 2]


BAD_UPLOADS = {
    "empty file": (b"", 400, "empty"),
    "not an image": (b"hello, this is text\n" * 10, 415, "not an image"),
    "truncated JPEG": (_truncated("JPEG"), 400, "truncated"),
    "truncated PNG": (_truncated("PNG"), 400, "truncated"),
    "pixel bomb 20000x20000": (_png_claiming(20000, 20000), 413, "pixels"),
    "over the pixel limit 8000x6000": (_png_claiming(8000, 6000), 413, "pixels"),
    "over the byte limit": (b"\xff" * (LIMIT + 1), 413, "limit"),
}


@pytest.mark.parametrize("route", ["/depth", "/pointcloud"])
@pytest.mark.parametrize("case", list(BAD_UPLOADS))
def test_bad_uploads_get_a_clear_4xx_and_the_service_stays_healthy(service, route, case):
    data, status, words = BAD_UPLOADS[case]
    r = post(service, route, data)
    assert r.status_code == status, r.text
    assert words in r.json()["detail"]
    assert_healthy(service)


def test_missing_field_and_empty_body(service):
    r = httpx.post(f"{service}/depth", files={"photo": ("x.png", png_bytes(tum_rgb(8, 8)))}, timeout=10)
    assert r.status_code == 422 and "image" in json.dumps(r.json()["detail"])
    r = httpx.post(f"{service}/pointcloud", timeout=10)
    assert r.status_code == 422
    assert_healthy(service)


def test_chunked_upload_over_the_limit_is_refused(service):
    def body():
        boundary = b'--xyz\r\nContent-Disposition: form-data; name="image"; filename="a"\r\n\r\n'
        yield boundary
        for _ in range(LIMIT // 65536 + 2):
            yield b"\0" * 65536
        yield b"\r\n--xyz--\r\n"

    r = httpx.post(
        f"{service}/depth", content=body(), timeout=30, headers={"content-type": "multipart/form-data; boundary=xyz"}
    )
    assert r.status_code == 413 and "limit" in r.json()["detail"]
    assert_healthy(service)


@pytest.mark.parametrize(
    "params",
    [
        {"fx": 0},
        {"fx": -5},
        {"fy": "nan"},
        {"fx": "inf"},
        {"cx": "nan"},
        {"cx": -1e12},
        {"fy": 1e-300},
        {"model": "no spaces allowed"},
        {"stride": 0},
        {"min_depth": 3, "max_depth": 1},
    ],
)
def test_bad_intrinsics_and_ranges_are_422(service, params):
    r = post(service, "/pointcloud", png_bytes(tum_rgb(32, 32)), params)
    assert r.status_code == 422, (params, r.text)
    assert "detail" in r.json()
    assert_healthy(service)


def _modes() -> dict[str, bytes]:
    rgb = tum_rgb(64, 48)
    grey16 = np.asarray(Image.fromarray(rgb).convert("L"), dtype=np.uint16) * 257
    frames = [Image.fromarray(rgb), Image.fromarray(rgb[::-1].copy())]
    gif = io.BytesIO()
    frames[0].save(gif, format="GIF", save_all=True, append_images=frames[1:], duration=100, loop=0)
    return {
        "16-bit grey PNG": png_bytes(grey16),
        "grey": encoded(Image.fromarray(rgb).convert("L"), "PNG"),
        "RGBA": encoded(Image.fromarray(rgb).convert("RGBA"), "PNG"),
        "palette": encoded(Image.fromarray(rgb).convert("P"), "PNG"),
        "CMYK JPEG": encoded(Image.fromarray(rgb).convert("CMYK"), "JPEG"),
        "animated GIF": gif.getvalue(),
        "1-bit": encoded(Image.fromarray(rgb).convert("1"), "PNG"),
        "WebP": encoded(Image.fromarray(rgb), "WEBP"),
    }


@pytest.mark.parametrize("mode", list(_modes()))
def test_any_image_mode_is_converted_not_refused(service, mode):
    r = post(service, "/depth", _modes()[mode])
    assert r.status_code == 200, r.text
    with Image.open(io.BytesIO(r.content)) as im:
        assert im.size == (64, 48)


def test_cors_only_for_configured_origins(service):
    preflight = {"Access-Control-Request-Method": "POST"}
    ok = httpx.options(f"{service}/depth", headers={"Origin": ALLOWED_ORIGIN, **preflight}, timeout=5)
    assert ok.headers.get("access-control-allow-origin") == ALLOWED_ORIGIN
    other = httpx.options(f"{service}/depth", headers={"Origin": "https://evil.example", **preflight}, timeout=5)
    assert "access-control-allow-origin" not in other.headers
    assert Settings().cors_origins == []  # the default allows none
    refused = post(service, "/depth", b"\xff" * (LIMIT + 1), headers={"Origin": ALLOWED_ORIGIN})
    assert refused.status_code == 413 and refused.headers["access-control-allow-origin"] == ALLOWED_ORIGIN


def test_models_and_metrics(service):
    models = httpx.get(f"{service}/v1/models", timeout=5).json()
    assert models["default"] == {"name": "tiny", "version": "0.1.0"}
    (entry,) = models["models"]
    assert entry["name"] == "tiny" and [v["version"] for v in entry["versions"]] == ["0.1.0"]
    version = entry["versions"][0]
    assert version["loaded"] and version["refused"] is None and version["card"]["data"][0]["licence"]
    post(service, "/depth", png_bytes(tum_rgb(32, 32)))
    text = httpx.get(f"{service}/metrics", timeout=5).text
    assert 'rgb2cloud_requests_total{method="POST",model="tiny:0.1.0",route="/depth",status="200"}' in text
    assert 'rgb2cloud_inference_seconds_count{model="tiny:0.1.0"}' in text
    assert "rgb2cloud_request_seconds_bucket" in text and "rgb2cloud_models_loaded 1.0" in text
    assert 'rgb2cloud_model_weights_bytes{model="tiny:0.1.0"}' in text and "process_resident_memory_bytes" in text
    assert "rgb2cloud_inference_in_flight" in text and "rgb2cloud_inference_queued" in text


@pytest.mark.slow
def test_overload_gets_503_with_retry_after_at_once(registry, model):
    big = png_bytes(np.tile(tum_rgb(), (3, 3, 1)))  # 1920x1440 at the model's focal length: slow enough to overlap

    async def burst(url: str) -> list[httpx.Response]:
        async with httpx.AsyncClient(timeout=60) as client:
            calls = [
                client.post(f"{url}/depth", files={"image": ("a.png", big)}, params=own_focal(model)) for _ in range(12)
            ]
            return await asyncio.gather(*calls)

    with running_service(
        registry=str(registry), max_queue="0", threads="1", inference_max_pixels=str(1920 * 1440)
    ) as running:
        url = running.url
        responses = asyncio.run(burst(url))
        statuses = [r.status_code for r in responses]
        assert set(statuses) <= {200, 503} and 200 in statuses and 503 in statuses, statuses
        for r in responses:
            if r.status_code == 503:
                assert r.headers["retry-after"] == "1" and "busy" in r.json()["detail"]
        assert_healthy(url)
        assert 'status="503"' in httpx.get(f"{url}/metrics", timeout=5).text


def start_service(registry: Path, **env: str) -> subprocess.CompletedProcess:
    """``python -m app`` on ``registry`` with ``env`` on top, expected to stop at startup (port 1 is never bound)."""
    base = {"RGB2CLOUD_REGISTRY": str(registry), "RGB2CLOUD_BUNDLED_REGISTRY": str(NO_REGISTRY), "RGB2CLOUD_PORT": "1"}
    command = [sys.executable, "-m", "app"]
    return subprocess.run(
        command, cwd=REPO, capture_output=True, text=True, timeout=60, env={**os.environ, **base, **env}
    )


def test_a_corrupt_model_stops_startup_with_one_clear_line(registry, tmp_path):
    broken = tmp_path / "weights"
    shutil.copytree(registry, broken)
    onnx_file = broken / "tiny" / "0.1.0" / "generator.onnx"
    onnx_file.write_bytes(onnx_file.read_bytes()[:-10])
    result = start_service(broken)
    assert result.returncode == 1
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "generator.onnx" in lines[0] and "sha256" in lines[0], result.stderr


@pytest.mark.parametrize(
    ("env", "says"),
    [
        ({"RGB2CLOUD_MODEL_NAME": "office"}, "RGB2CLOUD_MODEL_NAME is retired: set RGB2CLOUD_MODEL=NAME instead"),
        ({"RGB2CLOUD_MODELS": "office"}, "RGB2CLOUD_MODELS is not a setting"),
        ({"RGB2CLOUD_BACKEND": "torchscript"}, "RGB2CLOUD_BACKEND is retired: set RGB2CLOUD_ENGINE"),
        (
            {"RGB2CLOUD_ENGINE": "torchscript", "RGB2CLOUD_PRECISION": "int8"},
            "RGB2CLOUD_PRECISION=int8 needs another RGB2CLOUD_ENGINE than torchscript",
        ),
    ],
)
def test_a_retired_unknown_or_incoherent_setting_stops_startup_in_one_line(registry, env, says):
    """A deployment that still sets a renamed variable must not start and serve another model in silence."""
    result = start_service(registry, **env)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 1 and len(lines) == 1 and says in lines[0], result.stderr


def test_the_client_reads_host_and_port_from_the_settings(monkeypatch):
    from cli.service import service_url

    monkeypatch.setenv("RGB2CLOUD_HOST", "0.0.0.0")
    monkeypatch.setenv("RGB2CLOUD_PORT", "8123")
    assert service_url() == "http://127.0.0.1:8123"
    monkeypatch.setenv("RGB2CLOUD_PORT", "0")
    with pytest.raises(ValidationError):
        service_url()  # the client validates as the service does


def test_the_torchscript_engine_serves_the_same_depth(registry, service):
    rgb = tum_rgb(97, 71)
    onnx_png = post(service, "/depth", png_bytes(rgb)).content
    with running_service(registry=str(registry), engine="torchscript", threads="1") as running:
        r = post(running.url, "/depth", png_bytes(rgb))
        bf16 = post(running.url, "/depth?precision=bf16", png_bytes(rgb))
    assert r.status_code == 200 and r.headers["x-engine"] == "torchscript"
    assert bf16.status_code == 200 and bf16.headers["x-precision"] == "fp32"
    assert bf16.headers["x-precision-fallback"] == "bf16 asked for; the torchscript engine runs the fp32 graph only"
    with Image.open(io.BytesIO(r.content)) as a, Image.open(io.BytesIO(onnx_png)) as b:
        assert np.abs(np.asarray(a).astype(int) - np.asarray(b).astype(int)).max() <= 1


def test_the_model_dependency_follows_an_overridden_catalog(registry):
    """Handlers reach the catalog only through ``get_catalog``, so an override reaches every route.

    The app runs under uvicorn in this process (on a thread, on 127.0.0.1), so the override is live.
    """
    import threading

    import uvicorn

    from app.deps import get_catalog
    from app.main import create_app
    from harness.service import free_port

    settings = Settings(registry=registry, bundled_registry=NO_REGISTRY, threads=1)
    catalog = ModelCatalog(settings)
    catalog.load_default()
    app = create_app(settings, catalog)
    app.dependency_overrides[get_catalog] = lambda: ModelCatalog(settings)  # nothing loaded: not ready
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 30
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        photo = png_bytes(tum_rgb(32, 32))
        response = post(url, "/depth", photo)
        assert response.status_code == 503 and "not loaded yet" in response.json()["detail"]
        assert httpx.get(f"{url}/readyz", timeout=5).status_code == 503
        app.dependency_overrides.clear()
        assert post(url, "/depth", photo).status_code == 200
    finally:
        server.should_exit = True
        thread.join(timeout=10)


def test_the_service_names_the_installed_version(service):
    from importlib.metadata import version

    assert httpx.get(f"{service}/openapi.json", timeout=5).json()["info"]["version"] == version("rgb2cloud")
