"""The web page at GET /, in a real headless browser: Debian's chromium driven by Playwright.

The real service runs on 127.0.0.1 with the bundled default model; the page gets a real
frame (the TUM office, CC BY 4.0). Screenshots of each state are saved under
``runs/test-artifacts/web/``. Without chromium these tests fail, saying how to install it:
they are never skipped.
"""

from __future__ import annotations

import io
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, TUM_FRAME
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


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).is_file():
        pytest.fail("no chromium: `make test` installs Debian's package (apt-get install chromium)")
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as playwright:
        # SwiftShader: WebGL in software, as on a machine without a GPU.
        browser = playwright.chromium.launch(
            executable_path=CHROMIUM, args=["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
        )
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
    assert "rgb2cloud-7scenes 0.9.0" in facts and "inference" in facts and "from model" in facts
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
    # One request at a time and no queue: the page's two calls collide, and one gets 503 until the other is done.
    with running_service(
        bundled_registry=BUNDLED_REGISTRY, model="rgb2cloud-7scenes", threads="2", workers="1", max_queue="0"
    ) as busy:
        page, errors = open_page(browser, busy.url)
        page.evaluate(
            """() => { window.said = [];
            new MutationObserver(() => window.said.push(document.getElementById('status').textContent))
              .observe(document.getElementById('status'), {childList: true, characterData: true, subtree: true}); }"""
        )
        page.set_input_files("#photo", PHOTO)
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
