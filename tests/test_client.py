"""The client: real service for the happy path, a scripted transport for retries."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import httpx
import numpy as np
import pytest
from conftest import REPO, TUM_FRAME, png_header, run_cli
from PIL import Image
from plyfile import PlyData

from clients.photos import ClientOptions, run
from harness.service import free_port, running_service

#: Any base URL: the mocked transport answers every request itself.
MOCKED = "http://127.0.0.1:8000"


def _photos(folder, count=2):
    folder.mkdir()
    rgb = np.asarray(Image.open(TUM_FRAME / "TUM_color.png").convert("RGB"))
    for i in range(count):
        Image.fromarray(rgb[: 100 + i, :120]).save(folder / f"photo{i}.jpg")
    (folder / "notes.txt").write_text("not an image, skipped")
    return folder


def test_client_folder_against_the_real_service(registry, tmp_path):
    photos = _photos(tmp_path / "photos")
    with running_service(registry=str(registry), threads="1") as running:
        # No --url: the client finds the service from the same settings it was started with.
        port = running.url.rsplit(":", 1)[1]
        env = {**os.environ, "RGB2CLOUD_HOST": "0.0.0.0", "RGB2CLOUD_PORT": port}
        command = [sys.executable, "-m", "cli", "client", str(photos), "-o", str(tmp_path / "out"), "--pointcloud"]
        result = subprocess.run([*command, "--stride", "2"], cwd=REPO, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.count("wrote") == 4
    for i in range(2):
        with Image.open(tmp_path / "out" / f"photo{i}.depth.png") as im:
            assert im.size == (120, 100 + i) and np.asarray(im).dtype == np.uint16
        cloud = PlyData.read(str(tmp_path / "out" / f"photo{i}.ply"))
        assert 0 < cloud["vertex"].count <= 60 * (50 + i)


def test_client_retries_503_then_succeeds(tmp_path):
    photos = _photos(tmp_path / "photos", count=1)
    calls = []

    def handler(request: httpx.Request) -> httpx.Response:
        calls.append(request.url.path)
        if len(calls) < 3:
            return httpx.Response(503, headers={"Retry-After": "0"}, json={"detail": "busy"})
        return httpx.Response(200, content=b"PNG")

    outcomes = list(
        run(photos, ["depth"], tmp_path / "out", ClientOptions(url=MOCKED, retries=5), httpx.MockTransport(handler))
    )
    assert calls == ["/depth"] * 3
    assert outcomes[0][1].startswith("wrote") and (tmp_path / "out" / "photo0.depth.png").read_bytes() == b"PNG"


def test_an_unreachable_service_is_named_in_the_error(tmp_path):
    photos = _photos(tmp_path / "photos", count=1)
    url = f"http://127.0.0.1:{free_port()}"  # nothing listens there
    outcomes = list(run(photos, ["depth"], None, ClientOptions(url=url, retries=0)))
    assert outcomes[0][1].startswith(f"error: cannot reach the service at {url} (ConnectError")


def test_client_reports_errors_and_gives_up_after_retries(tmp_path):
    photos = _photos(tmp_path / "photos", count=1)
    busy = httpx.MockTransport(lambda r: httpx.Response(503, headers={"Retry-After": "0"}, json={"detail": "busy"}))
    outcomes = list(run(photos, ["depth"], None, ClientOptions(url=MOCKED, retries=2), busy))
    assert outcomes == [(photos / "photo0.jpg", "error: HTTP 503: busy")]


@pytest.mark.slow
def test_a_concurrent_batch_against_a_saturated_service_completes_and_resumes(registry, tmp_path):
    """Eight photos, six in flight, a service taking one at a time with no queue: 503s, retried, all done.

    Run again, it skips every output that exists; with one deleted, it redoes just that one."""
    photos = _photos(tmp_path / "photos", count=8)
    out = tmp_path / "out"
    with running_service(registry=str(registry), threads="1", workers="1", max_queue="0") as running:
        args = ["client", str(photos), "-o", str(out), "--url", running.url, "--concurrency", "6"]
        args += ["--model", "tiny", "--retries", "20"]
        first = run_cli(*args)
        assert first.stdout.count("wrote") == 8 and "error" not in first.stdout + first.stderr
        assert sorted(p.name for p in out.iterdir()) == [f"photo{i}.depth.png" for i in range(8)]  # no partial files
        again = run_cli(*args)
        assert again.stdout.count("skipped") == 8 and "wrote" not in again.stdout
        (out / "photo3.depth.png").unlink()
        resumed = run_cli(*args)
        assert resumed.stdout.count("skipped") == 7 and resumed.stdout.count("wrote") == 1
        metrics = httpx.get(f"{running.url}/metrics", timeout=5).text
    assert 'route="/depth",status="503"' in metrics  # the batch really met a full service


def test_client_names_each_photo_the_service_cannot_read_goes_on_and_counts_them(registry, tmp_path):
    """Random bytes named .jpg, a JPEG cut off halfway and a photo over the service's pixel limit each get a line
    naming the file and why; the good photos after them are written; the last line counts both, and the exit is 1."""
    photos = _photos(tmp_path / "photos")  # photo0.jpg, photo1.jpg
    good = (photos / "photo0.jpg").read_bytes()
    (photos / "a-noise.jpg").write_bytes(np.random.default_rng(0).bytes(5000))
    (photos / "b-cut.jpg").write_bytes(good[: len(good) // 2])
    (photos / "c-huge.png").write_bytes(png_header(30000, 30000))
    with running_service(registry=str(registry), threads="1") as running:
        command = [sys.executable, "-m", "cli", "client", str(photos), "-o", str(tmp_path / "out")]
        result = subprocess.run([*command, "--url", running.url], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 1
    # Each error line names its file (the progress bar shares stderr, so the name is found, not split off).
    errors = dict(re.findall(r"([\w-]+\.(?:jpg|png)): error: ([^\r\n]*)", result.stderr))
    assert "HTTP 415" in errors["a-noise.jpg"] and "not an image" in errors["a-noise.jpg"]
    assert "HTTP 400" in errors["b-cut.jpg"] and "truncated" in errors["b-cut.jpg"]
    assert "HTTP 413" in errors["c-huge.png"] and "too many pixels" in errors["c-huge.png"]
    assert result.stdout.count("wrote") == 2
    assert all((tmp_path / "out" / f"photo{i}.depth.png").exists() for i in (0, 1))
    last = result.stderr.strip().splitlines()[-1]
    assert last == "2 outputs written, 3 failed (HTTP 400: 1, HTTP 413: 1, HTTP 415: 1)", last
