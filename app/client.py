"""A client for the service: one image or a folder in, .depth.png / .ply files out.

Retries on 503 (busy or loading), honouring Retry-After, and on dropped
connections; every other error is reported per file and the rest go on.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
from tqdm import tqdm

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".webp", ".tif", ".tiff", ".bmp", ".gif"}
OUTPUTS = {"depth": ("/depth", ".depth.png"), "pointcloud": ("/pointcloud", ".ply")}


@dataclass
class ClientOptions:
    url: str = "http://127.0.0.1:8000"
    timeout_s: float = 60.0
    retries: int = 5
    cloud_params: dict | None = None  # query options for /pointcloud (stride, fx, ...)


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
    """Process every image; yields (image, 'wrote PATH' or 'error: ...') as it goes."""
    images = find_images(source)
    with httpx.Client(base_url=options.url, timeout=options.timeout_s, transport=transport) as client:
        for image in tqdm(images, desc="images", unit="img", disable=len(images) < 2):
            for kind in kinds:
                route, suffix = OUTPUTS[kind]
                target = (out_dir or image.parent) / (image.stem + suffix)
                try:
                    params = options.cloud_params if kind == "pointcloud" else None
                    response = request_with_retries(client, route, image, options, params)
                except httpx.HTTPError as e:
                    yield image, f"error: {type(e).__name__}: {e}"
                    continue
                if response.status_code != 200:
                    is_json = response.headers.get("content-type") == "application/json"
                    detail = response.json().get("detail") if is_json else response.text
                    yield image, f"error: HTTP {response.status_code}: {detail}"
                    continue
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(response.content)
                yield image, f"wrote {target}"


def server_timing(response: httpx.Response) -> dict[str, float]:
    """The service's ``Server-Timing`` header as {stage: ms}, in the order the stages ran."""
    stages = {}
    for entry in response.headers["server-timing"].split(","):
        name, duration = entry.strip().split(";dur=")
        stages[name] = float(duration)
    return stages
