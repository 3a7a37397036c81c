"""The serving benchmark's figures through a running service (``bench/serving.py``): requests one at a time,
split by ``Server-Timing``, each published version, and ``/depth`` under concurrent clients with the service's RSS.
"""

from __future__ import annotations

import argparse
import statistics
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

import httpx

from contract.card import list_versions
from harness.service import resident_mb, running_service, server_timing
from harness.timing import median_ms

if TYPE_CHECKING:
    from serving import Photo


def request_shares(client: httpx.Client, url: str, route: str, files: dict, r: int) -> dict[str, float]:
    """One request at a time: the server's stages (``Server-Timing``) and the rest of the client's wall clock."""
    rows = []
    for _ in range(r + 1):
        start = time.perf_counter()
        response = client.post(f"{url}{route}", files=files)
        total = (time.perf_counter() - start) * 1000
        rows.append({"total": total, **server_timing(response)})
    rows = rows[1:]  # the first request warms the connection
    shares = {name: statistics.median(row[name] for row in rows) for name in rows[0] if name != "total"}
    shares["HTTP, multipart and framework (total - server stages)"] = statistics.median(
        row["total"] - sum(v for k, v in row.items() if k != "total") for row in rows
    )
    shares["outside the model call"] = statistics.median(row["total"] - row["inference"] for row in rows)
    shares["total"] = statistics.median(row["total"] for row in rows)
    return shares


def concurrency(url: str, photo: Photo, r: int) -> dict[int, tuple[float, int, int, float]]:
    """/depth under 1-8 concurrent clients: (images/s, errors, requests, the generator's rate alone)."""
    files = {"image": ("photo.jpg", photo.data)}
    per_client = max(2, r // 2)

    def one_client(_: int) -> list[int]:
        with httpx.Client(timeout=120) as own:
            return [own.post(f"{url}/depth", files=files).status_code for _ in range(per_client)]

    throughput = {}
    for clients in (1, 2, 4, 8):
        # The generator's own rate is re-measured right before each level: on a shared,
        # noisy machine a rate taken minutes earlier is not a fair yardstick.
        alone = 1000 / photo.generator_ms(max(5, r // 2))
        start = time.perf_counter()
        with ThreadPoolExecutor(clients) as pool:
            statuses = [s for batch in pool.map(one_client, range(clients)) for s in batch]
        elapsed = time.perf_counter() - start
        throughput[clients] = (len(statuses) / elapsed, sum(s != 200 for s in statuses), len(statuses), alone)
    return throughput


@dataclass
class HttpFigures:
    """What the benchmark measures through a running service."""

    totals: dict[str, float]
    shares: dict[str, dict[str, float]]
    throughput: dict[int, tuple[float, int, int, float]]
    rss_mb: tuple[float, float]


def http_figures(args: argparse.Namespace, photo: Photo) -> HttpFigures:
    """Requests one at a time (each route, each version), then concurrent clients, through one service."""
    card, r = photo.model.card, args.repeats
    files = {"image": ("photo.jpg", photo.data)}
    on = {"registry": str(args.registry), "threads": str(args.threads), "model": args.model, "engine": "onnxruntime"}
    with running_service(**on) as service:
        client = httpx.Client(timeout=60)
        shares = {route: request_shares(client, service.url, route, files, r) for route in ("/depth", "/pointcloud")}
        totals = {f"HTTP total {route}": split["total"] for route, split in shares.items()}
        for version in list_versions(args.registry, card.name):  # each version through the same service
            ask = partial(client.post, f"{service.url}/depth", params={"model": f"{card.name}:{version}"}, files=files)
            totals[f"HTTP total /depth?model={card.name}:{version}"] = median_ms(ask, r)
        rss_before = resident_mb(service.pid)
        throughput = concurrency(service.url, photo, r)
        rss_after = resident_mb(service.pid)
    return HttpFigures(totals, shares, throughput, (rss_before, rss_after))


def share_tables(shares: dict[str, dict[str, float]]) -> str:
    out = (
        "\nOne request at a time, split by the service's `Server-Timing` header (server stages; `inference` is "
        "the model call: fit to grid + generator + decode to metres) and the client's wall clock:\n"
    )
    for route, split in shares.items():
        out += f"\n| {route} | median ms | share of total |\n|---|---|---|\n"
        for name, ms in split.items():
            label = f"**{name}**" if name == "outside the model call" else name
            out += f"| {label} | {ms:.1f} | {ms / split['total']:.0%} |\n"
    return out


def throughput_table(http: HttpFigures) -> str:
    out = (
        "\nThroughput of /depth under concurrent clients, against the generator's single-stream rate "
        "(1 / its median latency in this process, measured just before each row).\n\n"
        "| concurrent clients | requests | errors | images/s | generator alone, images/s | ratio |\n"
        "|---|---|---|---|---|---|\n"
    )
    for clients, (rate, errors, total, alone) in http.throughput.items():
        out += f"| {clients} | {total} | {errors} | {rate:.2f} | {alone:.2f} | {rate / alone:.0%} |\n"
    before, after = http.rss_mb
    return out + f"\nServer RSS: {before:.0f} MB before the concurrency runs, {after:.0f} MB after.\n"
