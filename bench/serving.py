"""Serving benchmark: per-stage times, the default path against every backend, Open3D, concurrency.

    python bench/serving.py --registry weights --model rgb2cloud-7scenes [--repeats 20] [--markdown docs/benchmarks.md]

Every figure is a median over ``--repeats`` runs on one 640x480 photo, taken in
one run on one machine, so the ratios between rows are what to read. The backends
table runs every published version of the default model on each backend
(ONNX Runtime, TorchScript, eager PyTorch), with its ratio to the fastest. Open3D
is optional (``pip install -e '.[bench]'``, and on Debian ``apt-get install
libusb-1.0-0``); without it that row is skipped.
"""

from __future__ import annotations

import argparse
import io
import os
import platform
import statistics
import tempfile
import time
import zlib
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path

import httpx
import numpy as np
from isal import isal_zlib
from PIL import Image

from app.catalog import ModelCatalog
from app.client import server_timing
from app.imaging import PNG_COMPRESS_LEVEL, decode_image, depth_png_rows, encode_depth_png
from app.loading import LoadedModel
from app.ply import encode_ply
from app.process import resident_mb, running_service
from app.settings import Settings
from contract.card import ONNX_FILE, TORCHSCRIPT_FILE, list_versions
from contract.codec import rgb_to_input
from contract.geometry import Intrinsics, pad_to_multiple, point_cloud
from contract.runtime import OnnxGenerator
from trainer.machine import cpu_description

REPO = Path(__file__).resolve().parents[1]

DEFAULT_IMAGE = REPO.parent / "shared/data/7scenes-redkitchen/frame-000900.color.jpg"


def median_ms(fn, repeats: int) -> float:
    fn()  # warm
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1000


def machine() -> str:
    import onnxruntime

    return f"{cpu_description()}, Python {platform.python_version()}, ONNX Runtime {onnxruntime.__version__}"


def depth_png_encoders(depth: np.ndarray, repeats: int) -> dict[str, tuple[float, int]]:
    """The depth PNG three ways, as (median ms, bytes): ours, ours with zlib's deflate, Pillow."""
    rows = depth_png_rows(depth)
    level = PNG_COMPRESS_LEVEL
    millimetres = Image.fromarray(np.clip(np.rint(depth * 1000.0), 0, 65535).astype(np.uint16))

    def pillow() -> bytes:
        buffer = io.BytesIO()
        millimetres.save(buffer, format="PNG", compress_level=level)
        return buffer.getvalue()

    candidates = {
        "rgb2cloud (`encode_depth_png`: Up filter, ISA-L deflate)": lambda: encode_depth_png(depth),
        "deflate only, ISA-L (what rgb2cloud uses)": lambda: isal_zlib.compress(rows, level),
        "deflate only, zlib": lambda: zlib.compress(rows, level),
        "Pillow (`Image.save`, its own filter choice, zlib)": pillow,
    }
    return {label: (median_ms(fn, repeats), len(fn())) for label, fn in candidates.items()}


def backend_times(model: LoadedModel, registry: Path, x: np.ndarray, threads: int, repeats: int) -> dict[str, float]:
    """Generator milliseconds of every version of the model on every backend installed, on input ``x``."""
    times = {}
    for version in list_versions(registry, model.card.name):
        folder = registry / model.card.name / version
        times |= {f"{version}, {backend}": ms for backend, ms in _version_times(folder, x, threads, repeats).items()}
    return times


def _version_times(folder: Path, x: np.ndarray, threads: int, repeats: int) -> dict[str, float]:
    session = OnnxGenerator(folder / ONNX_FILE, 1, threads).session
    name = session.get_inputs()[0].name
    times = {"ONNX Runtime": median_ms(lambda: session.run(None, {name: x}), repeats)}
    try:
        import torch

        from trainer.checkpoint import load_graph
    except ImportError:  # the serving install: ONNX Runtime only
        return times
    torch.set_num_threads(threads)
    scripted = torch.jit.load(str(folder / TORCHSCRIPT_FILE)).eval()
    eager, _, _ = load_graph(folder)  # the same weights and inference settings, eagerly
    xt = torch.from_numpy(x)
    with torch.inference_mode():
        times["TorchScript"] = median_ms(lambda: scripted(xt), repeats)
        times["eager PyTorch"] = median_ms(lambda: eager(xt), repeats)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--registry", type=Path, default=REPO / "weights")
    parser.add_argument("--model", default="rgb2cloud-7scenes", help="the default model: NAME or NAME:VERSION")
    parser.add_argument("--image", type=Path, default=DEFAULT_IMAGE)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    parser.add_argument("--markdown", type=Path, help="also write the tables here")
    args = parser.parse_args()

    settings = Settings(registry=args.registry, threads=args.threads, model=args.model)
    model = ModelCatalog(settings).load_default()
    card = model.card
    data = args.image.read_bytes()
    rgb = decode_image(data, settings.max_pixels).rgb
    h, w = rgb.shape[:2]
    m = card.input_multiple
    x = rgb_to_input(pad_to_multiple(rgb, m))
    session, name = model.generator.session, model.generator.input_name
    depth = model.predict_depth(rgb)
    c = card.camera
    k = Intrinsics(c.fx, c.fy, c.cx, c.cy, c.width, c.height).resized(w, h)
    points = point_cloud(depth, rgb, k)

    r = args.repeats
    stages = {
        "decode (JPEG -> RGB)": median_ms(lambda: decode_image(data, settings.max_pixels), r),
        "fit to grid (pad + normalise)": median_ms(lambda: rgb_to_input(pad_to_multiple(rgb, m)), r),
        "generator (ONNX Runtime)": median_ms(lambda: session.run(None, {name: x}), r),
        "depth decode (tanh -> metres)": median_ms(lambda: card.depth_encoding.decode(x[0, 0, :h, :w]), r),
        "depth PNG encode": median_ms(lambda: encode_depth_png(depth), r),
        "back-projection": median_ms(lambda: point_cloud(depth, rgb, k), r),
        "PLY encode": median_ms(lambda: encode_ply(points), r),
    }

    png_encoders = depth_png_encoders(depth, r)

    with running_service(registry=str(args.registry), threads=str(args.threads), model=args.model) as service:
        url = service.url
        client = httpx.Client(timeout=60)
        files = {"image": ("photo.jpg", data)}
        shares = {}
        for route in ("/depth", "/pointcloud"):
            rows = []
            for _ in range(r + 1):
                start = time.perf_counter()
                response = client.post(f"{url}{route}", files=files)
                total = (time.perf_counter() - start) * 1000
                rows.append({"total": total, **server_timing(response)})
            rows = rows[1:]  # the first request warms the connection
            stages[f"HTTP total {route}"] = statistics.median(row["total"] for row in rows)
            shares[route] = {name: statistics.median(row[name] for row in rows) for name in rows[0] if name != "total"}
            shares[route]["HTTP, multipart and framework (total - server stages)"] = statistics.median(
                row["total"] - sum(v for k, v in row.items() if k != "total") for row in rows
            )
            shares[route]["outside the model call"] = statistics.median(row["total"] - row["inference"] for row in rows)
            shares[route]["total"] = stages[f"HTTP total {route}"]
        for version in list_versions(args.registry, card.name):  # each version through the same service
            ask = partial(client.post, f"{url}/depth", params={"model": f"{card.name}:{version}"}, files=files)
            stages[f"HTTP total /depth?model={card.name}:{version}"] = median_ms(ask, r)
        rss_before = resident_mb(service.pid)
        throughput = {}
        per_client = max(2, r // 2)

        def one_client(_: int) -> list[int]:
            with httpx.Client(timeout=120) as own:
                return [own.post(f"{url}/depth", files=files).status_code for _ in range(per_client)]

        for clients in (1, 2, 4, 8):
            # The generator's own rate is re-measured right before each level: on a shared,
            # noisy machine a rate taken minutes earlier is not a fair yardstick.
            alone = 1000 / median_ms(lambda: session.run(None, {name: x}), max(5, r // 2))
            start = time.perf_counter()
            with ThreadPoolExecutor(clients) as pool:
                statuses = [s for batch in pool.map(one_client, range(clients)) for s in batch]
            elapsed = time.perf_counter() - start
            errors = sum(s != 200 for s in statuses)
            throughput[clients] = (len(statuses) / elapsed, errors, len(statuses), alone)
        rss_after = resident_mb(service.pid)

    backends = backend_times(model, args.registry, x, args.threads, r)
    default = f"{card.version}, ONNX Runtime"

    open3d_row = None
    with tempfile.TemporaryDirectory() as tmp:
        ours = median_ms(lambda: Path(tmp, "ours.ply").write_bytes(encode_ply(point_cloud(depth, rgb, k))), r)
        try:
            import open3d as o3d

            colour_image = o3d.geometry.Image(np.ascontiguousarray(rgb))
            depth_image = o3d.geometry.Image(np.ascontiguousarray(depth))
            intrinsic = o3d.camera.PinholeCameraIntrinsic(w, h, k.fx, k.fy, k.cx, k.cy)

            def open3d_cloud() -> None:
                rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
                    colour_image, depth_image, depth_scale=1.0, depth_trunc=1000.0, convert_rgb_to_intensity=False
                )
                cloud = o3d.geometry.PointCloud.create_from_rgbd_image(rgbd, intrinsic)
                o3d.io.write_point_cloud(str(Path(tmp, "open3d.ply")), cloud, write_ascii=False)

            open3d_row = median_ms(open3d_cloud, r)
        except ImportError:
            pass

    out = io.StringIO()
    out.write(
        f"Machine: {machine()}\n\nModel: {card.name} {card.version}, {w}x{h} photo "
        f"`{args.image.name}`, {args.threads} inference threads, medians of {r} runs.\n\n"
    )
    out.write("| stage | median ms |\n|---|---|\n")
    for stage, ms in stages.items():
        out.write(f"| {stage} | {ms:.1f} |\n")
    out.write(
        "\nOne request at a time, split by the service's `Server-Timing` header (server stages; `inference` is "
        "the model call: fit to grid + generator + decode to metres) and the client's wall clock:\n"
    )
    for route, split in shares.items():
        out.write(f"\n| {route} | median ms | share of total |\n|---|---|---|\n")
        for name, ms in split.items():
            label = f"**{name}**" if name == "outside the model call" else name
            out.write(f"| {label} | {ms:.1f} | {ms / split['total']:.0%} |\n")
    out.write(f"\n| depth PNG, {w}x{h}, compression level {PNG_COMPRESS_LEVEL} | median ms | KB |\n|---|---|---|\n")
    for label, (ms, size) in png_encoders.items():
        out.write(f"| {label} | {ms:.1f} | {size / 1000:.0f} |\n")
    fastest = min(backends.values())
    out.write(
        f"\nThe default path (**bold**: {card.name} {card.version} on ONNX Runtime, what `make serve` runs) against "
        "every version and backend, the generator call alone:\n"
    )
    out.write("\n| version, backend | median ms | vs the fastest |\n|---|---|---|\n")
    for backend, ms in backends.items():
        label = f"**{backend}**" if backend == default else backend
        out.write(f"| {label} | {ms:.1f} | {ms / fastest:.2f}x |\n")
    out.write("\n| back-projection + binary PLY to disk | median ms |\n|---|---|\n")
    out.write(f"| rgb2cloud (`point_cloud` + `encode_ply`) | {ours:.1f} |\n")
    if open3d_row is not None:
        out.write(
            f"| Open3D (`create_from_rgbd_image` + `write_point_cloud`) | {open3d_row:.1f} "
            f"({open3d_row / ours:.2f}x ours) |\n"
        )
    else:
        out.write("| Open3D | not installed (`pip install -e '.[bench]'`) |\n")
    out.write(
        "\nThroughput of /depth under concurrent clients, against the generator's single-stream rate "
        "(1 / its median latency in this process, measured just before each row).\n\n"
        "| concurrent clients | requests | errors | images/s | generator alone, images/s | ratio |\n"
        "|---|---|---|---|---|---|\n"
    )
    for clients, (rate, errors, total, alone) in throughput.items():
        out.write(f"| {clients} | {total} | {errors} | {rate:.2f} | {alone:.2f} | {rate / alone:.0%} |\n")
    out.write(f"\nServer RSS: {rss_before:.0f} MB before the concurrency runs, {rss_after:.0f} MB after.\n")
    text = out.getvalue()
    print(text)
    if args.markdown:
        args.markdown.write_text(
            f"# Serving benchmarks\n\nMade by `python bench/serving.py --registry {args.registry} "
            f"--model {args.model} --repeats {r} --markdown {args.markdown}`.\n\n{text}"
        )


if __name__ == "__main__":
    main()
