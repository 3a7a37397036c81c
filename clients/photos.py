"""A client for the service: one image or a folder in, .depth.png / .ply files out.

Sends ``concurrency`` requests at once, under one progress bar. Retries on 503
(busy or loading), honouring Retry-After, and on dropped connections; every other
error is reported per file and the rest go on. Outputs that already exist are
skipped, so running the same command again resumes an interrupted batch; each
output is written under a temporary name and renamed, so no half-written file is
ever taken for a finished one.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import httpx
from tqdm import tqdm

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".webp", ".tif", ".tiff", ".bmp", ".gif"}
OUTPUTS = {"depth": ("/depth", ".depth.png"), "pointcloud": ("/pointcloud", ".ply")}


@dataclass
class ClientOptions:
    #: The service's base URL (the CLI's default is the service's own settings: ``cli.service.service_url``).
    url: str
    timeout_s: float = 60.0
    retries: int = 5
    concurrency: int = 1
    overwrite: bool = False
    params: dict | None = None  # query options for both routes (model, fx, ...)
    cloud_params: dict | None = None  # query options for /pointcloud only (stride, ...)


def find_images(source: Path) -> list[Path]:
    if source.is_dir():
        return sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
    return [source]


def request_with_retries(
    client: httpx.Client, route: str, image: Path, options: ClientOptions, params: dict | None = None
) -> httpx.Response:
    """POST one image; 503s and dropped connections are retried up to ``options.retries`` times."""
    data = image.read_bytes()
    for attempt in range(options.retries + 1):
        try:
            response = client.post(route, files={"image": (image.name, data)}, params=params)
        except httpx.TransportError:
            if attempt == options.retries:
                raise
            time.sleep(min(2**attempt, 30))
            continue
        if response.status_code != 503 or attempt == options.retries:
            return response
        time.sleep(float(response.headers.get("retry-after", 2**attempt)))
    raise AssertionError("unreachable")


def run(
    source: Path,
    kinds: list[str],
    out_dir: Path | None,
    options: ClientOptions,
    transport: httpx.BaseTransport | None = None,
) -> Iterator[tuple[Path, str]]:
    """Process every image; yields (image, 'wrote PATH', 'skipped PATH (exists)' or 'error: ...') as it goes."""
    jobs = []
    for image in find_images(source):
        for kind in kinds:
            target = (out_dir or image.parent) / (image.stem + OUTPUTS[kind][1])
            if target.exists() and not options.overwrite:
                yield image, f"skipped {target} (exists)"
            else:
                jobs.append((image, kind, target))
    limits = httpx.Limits(max_connections=options.concurrency, max_keepalive_connections=options.concurrency)
    left = {image: sum(job[0] == image for job in jobs) for image, _, _ in jobs}  # outputs still due per photo
    with (
        httpx.Client(base_url=options.url, timeout=options.timeout_s, transport=transport, limits=limits) as client,
        ThreadPoolExecutor(options.concurrency) as pool,
        tqdm(total=len(left), desc="photos", unit="photo", disable=len(left) < 2) as bar,
    ):
        futures = {pool.submit(_one, client, image, kind, target, options): image for image, kind, target in jobs}
        for future in as_completed(futures):
            image = futures[future]
            left[image] -= 1
            if not left[image]:
                bar.update()
            yield image, future.result()


def _one(client: httpx.Client, image: Path, kind: str, target: Path, options: ClientOptions) -> str:
    route = OUTPUTS[kind][0]
    params = {**(options.params or {}), **((options.cloud_params or {}) if kind == "pointcloud" else {})}
    try:
        response = request_with_retries(client, route, image, options, params)
    except httpx.TransportError as e:
        return f"error: cannot reach the service at {options.url} ({type(e).__name__}: {e})"
    except httpx.HTTPError as e:
        return f"error: {type(e).__name__}: {e}"
    if response.status_code != 200:
        is_json = response.headers.get("content-type") == "application/json"
        detail = response.json().get("detail") if is_json else response.text
        return f"error: HTTP {response.status_code}: {detail}"
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_name(f".{target.name}.{os.getpid()}.part")
    partial.write_bytes(response.content)
    partial.replace(target)
    return f"wrote {target}"


class OutputTally:
    """The client's last line: outputs written, found already there, and failed, by why (a photo the service
    could not read is one HTTP 4xx among them, and the batch went on past it)."""

    def __init__(self) -> None:
        self.written = self.existing = 0
        self.failed: dict[str, int] = {}

    def add(self, outcome: str) -> None:
        if outcome.startswith("wrote"):
            self.written += 1
        elif outcome.startswith("skipped"):
            self.existing += 1
        else:  # "error: HTTP 415: ...", "error: cannot reach the service at URL (...)", "error: ReadTimeout: ..."
            error = outcome.removeprefix("error: ")
            why = "cannot reach the service" if error.startswith("cannot reach") else error.split(":")[0]
            self.failed[why] = self.failed.get(why, 0) + 1

    def summary(self) -> str:
        parts = [f"{self.written} outputs written"]
        if self.existing:
            parts.append(f"{self.existing} already there")
        if self.failed:
            whys = ", ".join(f"{why}: {count}" for why, count in sorted(self.failed.items()))
            parts.append(f"{sum(self.failed.values())} failed ({whys})")
        return ", ".join(parts)
