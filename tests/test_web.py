"""The web page at GET /, in a real headless browser: Debian's chromium driven by Playwright.

The real service runs on 127.0.0.1 with the bundled default model; the page gets a real
frame (the TUM office, CC BY 4.0). Screenshots of each state are saved under
``runs/test-artifacts/web/``. Without chromium these tests fail, saying how to install it:
they are never skipped.
"""

from __future__ import annotations

import io
import itertools
import shutil
import threading
from pathlib import Path

import httpx
import numpy as np
import pytest
from conftest import REPO, SEVEN_SCENES, TUM_FRAME
from PIL import Image
from plyfile import PlyData

from harness.service import BUNDLED_REGISTRY, running_service

#: Real processes, networks or browsers: the full suite (`make test`) runs these, `-m 'not slow'` skips them.
pytestmark = pytest.mark.slow

ARTIFACTS = REPO / "runs" / "test-artifacts" / "web"
PHOTO = TUM_FRAME / "TUM_color.png"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
#: The viewer's clear colour (0.07, 0.08, 0.1) in 8 bits.
BACKGROUND = np.array([18, 20, 26])


#: SwiftShader: WebGL in software, as on a machine without a GPU.
SOFTWARE_GL = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


@pytest.fixture(scope="module")
def playwright():
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).is_file():
        pytest.fail("no chromium: `make test` installs Debian's package (apt-get install chromium)")
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as running:
        yield running


@pytest.fixture(scope="module")
def browser(playwright):
    browser = playwright.chromium.launch(executable_path=CHROMIUM, args=SOFTWARE_GL)
    yield browser
    browser.close()


@pytest.fixture(scope="module")
def service():
    with running_service(bundled_registry=BUNDLED_REGISTRY, model="rgb2cloud-7scenes", threads="2") as running:
        yield running.url


def open_page(browser, url: str, width: int = 1200, height: int = 1400):
    page = browser.new_page(viewport={"width": width, "height": height}, accept_downloads=True)
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(f"{url}/")
    page.wait_for_function("document.getElementById('model').options.length > 1")
    return page, errors


def wait_done(page) -> None:
    page.wait_for_function(
        "['Done.'].includes(document.getElementById('status').textContent) || !document.getElementById('error').hidden",
        timeout=120_000,
    )


def canvas_pixels(page, name: str) -> np.ndarray:
    path = ARTIFACTS / f"{name}.png"
    page.locator("#cloud").screenshot(path=path)
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), dtype=np.int16)


def drawn_share(pixels: np.ndarray) -> float:
    """The share of the canvas that is not background: where points were drawn."""
    return float(np.mean(np.abs(pixels - BACKGROUND).sum(axis=2) > 30))


def changed_share(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.mean(np.abs(a - b).sum(axis=2) > 30))


def test_a_photo_gives_depth_and_a_point_cloud_to_orbit_and_download(browser, service):
    page, errors = open_page(browser, service)
    models = page.eval_on_selector("#model", "s => [...s.options].map(o => o.value)")
    assert "rgb2cloud-7scenes" in models and "rgb2cloud-7scenes:0.8.1" in models  # from /v1/models
    page.screenshot(path=ARTIFACTS / "1-empty.png", full_page=True)

    page.set_input_files("#photo", PHOTO)
    wait_done(page)
    assert page.locator("#error").is_hidden(), page.inner_text("#error")
    assert page.eval_on_selector("#depth", "img => img.complete && img.naturalWidth") == 640  # the depth preview
    page.screenshot(path=ARTIFACTS / "2-result.png", full_page=True)
    facts = page.inner_text("#facts")
    assert "rgb2cloud-7scenes 0.9.1" in facts and "inference" in facts and "from model" in facts
    points = int(facts.split("Points")[1].split()[0].replace(",", ""))
    assert points == 320 * 240  # stride 2 on a 640x480 photo: every depth is in range

    first = canvas_pixels(page, "3-cloud")
    assert drawn_share(first) > 0.3  # the cloud covers the view it was taken from

    box = page.locator("#cloud").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 160, y + 60, steps=8)
    page.mouse.up()
    orbited = canvas_pixels(page, "4-orbited")
    assert changed_share(first, orbited) > 0.2 and drawn_share(orbited) > 0.05

    page.mouse.wheel(0, 600)  # zoom out
    zoomed = canvas_pixels(page, "5-zoomed-out")
    assert drawn_share(zoomed) < drawn_share(orbited)
    page.click("#reset-view")
    assert changed_share(first, canvas_pixels(page, "6-reset")) < 0.02
    page.fill("#point-size", "6")
    page.dispatch_event("#point-size", "input")
    assert drawn_share(canvas_pixels(page, "7-bigger-points")) > drawn_share(first)

    with page.expect_download() as download:
        page.click("#download-ply")
    ply = PlyData.read(io.BytesIO(Path(download.value.path()).read_bytes()))
    assert ply["vertex"].count == points and download.value.suggested_filename == "TUM_color.ply"
    with page.expect_download() as download:
        page.click("#download-png")
    with Image.open(download.value.path()) as depth:
        assert depth.size == (640, 480) and np.asarray(depth).dtype == np.uint16
    assert errors == []


def test_the_api_message_is_shown_for_a_file_that_is_not_an_image(browser, service, tmp_path):
    page, errors = open_page(browser, service)
    notes = tmp_path / "notes.txt"
    notes.write_text("this is not a photo\n" * 20)
    page.set_input_files("#photo", notes)
    wait_done(page)
    message = page.inner_text("#error")
    assert "not an image we can read" in message  # the API's own words (415)
    assert page.inner_text("#status") == "" and page.locator("#run").is_enabled()  # no endless spinner
    page.screenshot(path=ARTIFACTS / "8-not-an-image.png", full_page=True)
    page.fill("#fx", "-3")  # a 422 from the API, in plain words
    page.set_input_files("#photo", PHOTO)
    wait_done(page)
    assert "fx" in page.inner_text("#error") and "greater than or equal" in page.inner_text("#error")
    assert errors == []


def test_a_busy_service_is_retried_after_retry_after(browser):
    # One request at a time and no queue. Two clients of ours keep the one place taken until the page has been
    # told it is busy (its own two calls collide only where inference is slower than their arrival, so a fast
    # CPU would decide the test), then stop: the page's retry after Retry-After gets in.
    with running_service(
        bundled_registry=BUNDLED_REGISTRY, model="rgb2cloud-7scenes", threads="2", workers="1", max_queue="0"
    ) as busy:
        page, errors = open_page(browser, busy.url)
        page.evaluate(
            """() => { window.said = [];
            new MutationObserver(() => window.said.push(document.getElementById('status').textContent))
              .observe(document.getElementById('status'), {childList: true, characterData: true, subtree: true}); }"""
        )
        told = threading.Event()

        def occupy() -> None:
            with httpx.Client(base_url=busy.url, timeout=30) as client:
                while not told.is_set():
                    client.post("/depth", files={"image": PHOTO.read_bytes()})  # a 503 is as good: keep trying

        occupiers = [threading.Thread(target=occupy) for _ in range(2)]
        for thread in occupiers:
            thread.start()
        try:
            page.set_input_files("#photo", PHOTO)
            page.wait_for_function("window.said.some((line) => line.includes('busy'))", timeout=30_000)
        finally:
            told.set()
            for thread in occupiers:
                thread.join()
        wait_done(page)
        said = page.evaluate("window.said")
        assert any("busy" in line and "trying again in 1 s" in line for line in said), said
        assert page.locator("#error").is_hidden() and page.inner_text("#status") == "Done."
        assert errors == []


def test_the_page_fits_a_phone(browser, service):
    page, errors = open_page(browser, service, width=390, height=844)
    page.set_input_files("#photo", PHOTO)
    wait_done(page)
    assert page.evaluate("document.documentElement.scrollWidth") <= 390  # nothing wider than the screen
    canvas = page.locator("#cloud").bounding_box()
    assert canvas["width"] <= 390 and drawn_share(canvas_pixels(page, "9-phone-cloud")) > 0.2
    page.screenshot(path=ARTIFACTS / "9-phone.png", full_page=True)
    assert errors == []


def test_touch_drags_orbit_and_a_pinch_zooms(browser, service):
    """Touch input through the browser's own touch events (CDP), as a phone's screen sends them."""
    context = browser.new_context(viewport={"width": 390, "height": 844}, has_touch=True, is_mobile=True)
    page = context.new_page()
    page.goto(f"{service}/")
    page.wait_for_function("document.getElementById('model').options.length > 1")
    page.set_input_files("#photo", PHOTO)
    wait_done(page)
    page.locator("#cloud").scroll_into_view_if_needed()
    cdp = context.new_cdp_session(page)
    box = page.locator("#cloud").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2

    def touch(kind: str, *points: tuple[float, float]) -> None:
        touches = [{"x": px, "y": py, "id": i} for i, (px, py) in enumerate(points)]
        cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": touches})

    first = canvas_pixels(page, "10-touch-start")
    touch("touchStart", (x, y))
    for step in range(1, 9):
        touch("touchMove", (x + 12 * step, y))
    touch("touchEnd")
    dragged = canvas_pixels(page, "11-touch-orbited")
    assert changed_share(first, dragged) > 0.2

    page.click("#reset-view")
    before = canvas_pixels(page, "12-touch-reset")
    touch("touchStart", (x - 20, y), (x + 20, y))
    for step in range(1, 9):
        touch("touchMove", (x - 20 - 10 * step, y), (x + 20 + 10 * step, y))
    touch("touchEnd")
    pinched = canvas_pixels(page, "13-pinched")
    # Fingers apart bring the eye closer: the points (a fixed size on screen) spread apart and part leave the view.
    assert changed_share(before, pinched) > 0.2 and drawn_share(pinched) < drawn_share(before) - 0.1
    context.close()


def write_y4m(path: Path, frames: list[Path], fps: int = 30) -> Path:
    """A Y4M video of the frames (4:2:0, BT.601 studio range): what Chromium's fake camera plays, in a loop."""
    with path.open("wb") as out:
        out.write(f"YUV4MPEG2 W640 H480 F{fps}:1 Ip A1:1 C420jpeg\n".encode())
        for frame in frames:
            rgb = np.asarray(Image.open(frame).convert("RGB"), dtype=np.float64) / 255
            r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
            y = 16 + 65.481 * r + 128.553 * g + 24.966 * b
            u = 128 - 37.797 * r - 74.203 * g + 112.0 * b
            v = 128 + 112.0 * r - 93.786 * g - 18.214 * b
            halves = [c.reshape(240, 2, 320, 2).mean(axis=(1, 3)) for c in (u, v)]
            out.write(b"FRAME\n")
            for plane in (y, *halves):
                out.write(np.clip(np.rint(plane), 0, 255).astype(np.uint8).tobytes())
    return path


def test_live_mode_streams_a_camera_s_depth_and_cloud(playwright, service, tmp_path):
    """Chromium's fake camera plays 7-Scenes frames 850-969 in a 4 s loop; the page streams them over /v1/stream.

    The loop is long against the page's answers (a few a second here), so two views a few answers apart
    never show the same camera frame."""
    kitchen = [SEVEN_SCENES / f"frame-{n:06d}.color.jpg" for n in range(850, 970)]
    video = write_y4m(tmp_path / "kitchen.y4m", kitchen)
    fake_camera = [
        "--use-fake-device-for-media-stream",
        "--use-fake-ui-for-media-stream",
        f"--use-file-for-fake-video-capture={video}",
    ]
    browser = playwright.chromium.launch(executable_path=CHROMIUM, args=[*SOFTWARE_GL, *fake_camera])
    try:
        page, errors = open_page(browser, service)
        page.fill("#stride", "4")
        page.click("#live")
        page.wait_for_function("window.liveStats && window.liveStats.answered >= 10", timeout=120_000)
        depth_views = []
        for i in range(3):
            path = ARTIFACTS / f"14-live-depth-{i}.png"
            page.locator("#live-depth").screenshot(path=path)
            with Image.open(path) as im:
                depth_views.append(np.asarray(im.convert("RGB"), dtype=np.int16))
            seen = page.evaluate("window.liveStats.answered")
            page.wait_for_function(f"window.liveStats.answered >= {seen + 3}", timeout=60_000)  # newer answers
        # The camera moves through the kitchen: the depth changes from frame to frame.
        assert all(changed_share(a, b) > 0.05 for a, b in itertools.pairwise(depth_views))
        cloud = page.locator("#live-cloud")
        cloud.screenshot(path=ARTIFACTS / "15-live-cloud.png")
        with Image.open(ARTIFACTS / "15-live-cloud.png") as im:
            assert drawn_share(np.asarray(im.convert("RGB"), dtype=np.int16)) > 0.2

        page.fill("#fx", "700")
        page.dispatch_event("#fx", "change")
        page.wait_for_function("document.getElementById('live-stats').textContent.includes('fx 700.0 (query)')")
        stats = page.evaluate("window.liveStats")
        page.screenshot(path=ARTIFACTS / "16-live.png", full_page=True)
        (ARTIFACTS / "16-live.txt").write_text(f"{stats}\n")
        # Frames flow at whatever rate this machine reaches with the browser drawing in software beside the
        # service on the same cores (16-live.txt keeps it); bench/stream.py measures the service's own rate.
        assert stats["fps"] >= 1 and stats["latencyMs"] > 0 and stats["errors"] == 0, stats
        assert "frames/s" in page.inner_text("#live-stats") and "skipped by the service" in page.inner_text(
            "#live-stats"
        )

        page.click("#live")
        answered = page.evaluate("window.liveStats.answered")
        page.wait_for_timeout(1000)
        assert page.evaluate("window.liveStats.answered") <= answered + 2  # what was in flight, then nothing
        assert page.inner_text("#live") == "Live: start the camera" and page.locator("#error").is_hidden()
        assert errors == []
    finally:
        browser.close()
