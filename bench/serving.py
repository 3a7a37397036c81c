"""Serving benchmark: per-stage times, the default path against every backend, Open3D, concurrency.

    python bench/serving.py --registry weights --model rgb2cloud-7scenes [--repeats 20] [--markdown docs/benchmarks.md]
    python bench/serving.py --engines [--repeats 20]     # the engine rows alone (bench/engines.py), on any CPU

Every figure is a median over ``--repeats`` runs on one 640x480 photo, taken in
one run on one machine, so the ratios between rows are what to read. The backends
table runs every published version of the default model on each backend
(ONNX Runtime, TorchScript, eager PyTorch), with its ratio to the fastest. Open3D
is optional (``pip install -e '.[bench]'``, and on Debian ``apt-get install
libusb-1.0-0``); without it that row is skipped. All but the engine rows run ONNX Runtime fp32. The figures
through a running service are bench/serving_http.py's, the engine rows bench/engines.py's.
"""

from __future__ import annotations

import argparse
import io
import os
import platform
import tempfile
import zlib
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import httpx
import numpy as np
from engines import engine_rows
from isal import isal_zlib
from PIL import Image
from serving_http import http_figures, share_tables, throughput_table

from app.catalog import ModelCatalog
from app.imaging import open_upload
from app.loading import LoadedModel
from app.settings import Settings
from contract.card import INT8_ONNX_FILE, ONNX_FILE, TORCHSCRIPT_FILE, ModelCard, list_versions
from contract.codec import rgb_to_input
from contract.encodings import PNG_COMPRESS_LEVEL, depth_png_rows, encode_depth_png, encode_ply
from contract.geometry import Intrinsics, pad_to_multiple, point_cloud
from contract.runtime import OnnxGenerator
from harness.service import running_service
from harness.timing import interleaved_ms, median_ms
from trainer.machine import SPEED_FLAGS, cpu_description, cpu_flags

REPO = Path(__file__).resolve().parents[1]

DEFAULT_IMAGE = REPO.parent / "shared/data/7scenes-redkitchen/frame-000900.color.jpg"


def machine() -> str:
    import onnxruntime

    flags = ", ".join(sorted(set(SPEED_FLAGS) & cpu_flags())) or "none"
    return (
        f"{cpu_description()} (int8 and bf16 flags: {flags}), Python {platform.python_version()}, "
        f"ONNX Runtime {onnxruntime.__version__}"
    )


def int8_times(args: argparse.Namespace, photo: Photo) -> dict[str, float]:
    """fp32 against int8 in one run: the generator call, and HTTP /depth through one service.

    The default version is published again with ``export --precision int8`` into a scratch registry
    (as ``NAME-int8``), so the int8 graph is exactly what that command makes. Empty without the
    trainer (the serving install), which cannot export.
    """
    try:
        from trainer.export import export_and_publish
    except ImportError:
        return {}
    card, r = photo.model.card, args.repeats
    with tempfile.TemporaryDirectory() as tmp:
        name = f"{card.name}-int8"
        folder = export_and_publish(
            photo.model.path, Path(tmp), name, card.version, card.metrics, args.image, precision="int8"
        )
        files = {"fp32": ONNX_FILE, "int8": INT8_ONNX_FILE}
        graphs = {p: OnnxGenerator(folder / f, 1, args.threads).session for p, f in files.items()}
        calls = {f"generator {p}": partial(s.run, None, {s.get_inputs()[0].name: photo.x}) for p, s in graphs.items()}
        times = interleaved_ms(calls, r)
        upload = {"image": ("photo.jpg", photo.data)}
        model = f"{name}:{card.version}"
        service = running_service(registry=tmp, threads=str(args.threads), model=model, engine="onnxruntime")
        with service as running, httpx.Client(timeout=60) as client:
            post = partial(client.post, f"{running.url}/depth", files=upload)
            calls = {f"HTTP /depth?precision={p}": partial(post, params={"precision": p}) for p in graphs}
            times |= interleaved_ms(calls, r)
    return times


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
    eager, _ = load_graph(folder)  # the same weights and inference settings, eagerly
    xt = torch.from_numpy(x)
    with torch.inference_mode():
        times["TorchScript"] = median_ms(lambda: scripted(xt), repeats)
        times["eager PyTorch"] = median_ms(lambda: eager(xt), repeats)
    return times


@dataclass
class Photo:
    """The benchmark's one photo, everything the stages need of it, and the model it runs on."""

    data: bytes
    rgb: np.ndarray
    x: np.ndarray
    depth: np.ndarray
    camera: Intrinsics
    model: LoadedModel

    @classmethod
    def load(cls, path: Path, model: LoadedModel, max_pixels: int) -> Photo:
        data = path.read_bytes()
        rgb = open_upload(data, max_pixels).rgb()
        h, w = rgb.shape[:2]
        c = model.card.camera
        camera = Intrinsics(c.fx, c.fy, c.cx, c.cy, c.width, c.height).resized(w, h)
        x = rgb_to_input(pad_to_multiple(rgb, model.card.input_multiple))
        return cls(data, rgb, x, model.predict_depth(rgb), camera, model)

    def generator_ms(self, repeats: int) -> float:
        session, name = self.model.generators["fp32"].session, self.model.generators["fp32"].input_name
        return median_ms(lambda: session.run(None, {name: self.x}), repeats)


def stage_times(photo: Photo, max_pixels: int, r: int) -> dict[str, float]:
    """Each stage of a request, in process, median ms."""
    rgb, depth, k, card = photo.rgb, photo.depth, photo.camera, photo.model.card
    h, w = rgb.shape[:2]
    points = point_cloud(depth, rgb, k)
    return {
        "decode (JPEG -> RGB)": median_ms(lambda: open_upload(photo.data, max_pixels).rgb(), r),
        "fit to grid (pad + normalise)": median_ms(lambda: rgb_to_input(pad_to_multiple(rgb, card.input_multiple)), r),
        "generator (ONNX Runtime)": photo.generator_ms(r),
        "depth decode (tanh -> metres)": median_ms(lambda: card.depth_encoding.decode(photo.x[0, 0, :h, :w]), r),
        "depth PNG encode": median_ms(lambda: encode_depth_png(depth), r),
        "back-projection": median_ms(lambda: point_cloud(depth, rgb, k), r),
        "PLY encode": median_ms(lambda: encode_ply(points), r),
    }


def ply_times(photo: Photo, r: int) -> tuple[float, float | None]:
    """Back-projection and a binary PLY on disk: ours, and Open3D's where it is installed (else None)."""
    rgb, depth, k = photo.rgb, photo.depth, photo.camera
    h, w = rgb.shape[:2]
    with tempfile.TemporaryDirectory() as tmp:
        ours = median_ms(lambda: Path(tmp, "ours.ply").write_bytes(encode_ply(point_cloud(depth, rgb, k))), r)
        try:
            import open3d as o3d
        except ImportError:
            return ours, None
        colour_image = o3d.geometry.Image(np.ascontiguousarray(rgb))
        depth_image = o3d.geometry.Image(np.ascontiguousarray(depth))
        intrinsic = o3d.camera.PinholeCameraIntrinsic(w, h, k.fx, k.fy, k.cx, k.cy)

        def open3d_cloud() -> None:
            rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
                colour_image, depth_image, depth_scale=1.0, depth_trunc=1000.0, convert_rgb_to_intensity=False
            )
            cloud = o3d.geometry.PointCloud.create_from_rgbd_image(rgbd, intrinsic)
            o3d.io.write_point_cloud(str(Path(tmp, "open3d.ply")), cloud, write_ascii=False)

        return ours, median_ms(open3d_cloud, r)


def stage_table(stages: dict[str, float]) -> str:
    return "| stage | median ms |\n|---|---|\n" + "".join(f"| {stage} | {ms:.1f} |\n" for stage, ms in stages.items())


def png_table(encoders: dict[str, tuple[float, int]], w: int, h: int) -> str:
    out = f"\n| depth PNG, {w}x{h}, compression level {PNG_COMPRESS_LEVEL} | median ms | KB |\n|---|---|---|\n"
    return out + "".join(f"| {label} | {ms:.1f} | {size / 1000:.0f} |\n" for label, (ms, size) in encoders.items())


def backend_table(backends: dict[str, float], card: ModelCard) -> str:
    fastest = min(backends.values())
    default = f"{card.version}, ONNX Runtime"
    out = (
        f"\nThe default path (**bold**: {card.name} {card.version} on ONNX Runtime, what `make serve` runs) against "
        "every version and backend, the generator call alone:\n"
        "\n| version, backend | median ms | vs the fastest |\n|---|---|---|\n"
    )
    for backend, ms in backends.items():
        label = f"**{backend}**" if backend == default else backend
        out += f"| {label} | {ms:.1f} | {ms / fastest:.2f}x |\n"
    return out


def int8_table(times: dict[str, float], card: ModelCard) -> str:
    if not times:
        return "\nint8: not measured (the serving install has no trainer to export an int8 graph).\n"
    out = (
        f"\n{card.name} {card.version} published again with `export --precision int8`, fp32 and int8 taking turns "
        "in one run:\n\n| int8 against fp32 | median ms | speed-up |\n|---|---|---|\n"
    )
    for label, ms in times.items():
        fp32 = times[label.replace("int8", "fp32")]
        out += f"| {label} | {ms:.1f} | {fp32 / ms:.2f}x |\n"
    return out


def ply_table(ours: float, open3d: float | None) -> str:
    out = "\n| back-projection + binary PLY to disk | median ms |\n|---|---|\n"
    out += f"| rgb2cloud (`point_cloud` + `encode_ply`) | {ours:.1f} |\n"
    if open3d is None:
        return out + "| Open3D | not installed (`pip install -e '.[bench]'`) |\n"
    return (
        out
        + f"| Open3D (`create_from_rgbd_image` + `write_point_cloud`) | {open3d:.1f} ({open3d / ours:.2f}x ours) |\n"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--registry", type=Path, default=REPO / "weights")
    parser.add_argument("--model", default="rgb2cloud-7scenes", help="the default model: NAME or NAME:VERSION")
    parser.add_argument("--image", type=Path, default=DEFAULT_IMAGE)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--threads", type=int, default=os.cpu_count())
    parser.add_argument("--markdown", type=Path, help="also write the tables here")
    parser.add_argument("--engines", action="store_true", help="print the engine rows alone (any CPU)")
    args = parser.parse_args()

    settings = Settings(registry=args.registry, threads=args.threads, model=args.model, engine="onnxruntime")
    model = ModelCatalog(settings).load_default()
    photo = Photo.load(args.image, model, settings.max_pixels)
    engines = engine_rows(args, model.path, photo.rgb, photo.data)
    if args.engines:
        print(f"Machine: {machine()}\n{engines}")
        return
    r = args.repeats
    stages = stage_times(photo, settings.max_pixels, r)
    png_encoders = depth_png_encoders(photo.depth, r)
    http = http_figures(args, photo)
    backends = backend_times(model, args.registry, photo.x, args.threads, r)
    ours, open3d = ply_times(photo, r)
    int8 = int8_times(args, photo)

    h, w = photo.rgb.shape[:2]
    card = model.card
    text = (
        f"Machine: {machine()}\n\nModel: {card.name} {card.version}, {w}x{h} photo "
        f"`{args.image.name}`, {args.threads} inference threads, medians of {r} runs.\n\n"
        + stage_table(stages | http.totals)
        + share_tables(http.shares)
        + png_table(png_encoders, w, h)
        + backend_table(backends, card)
        + int8_table(int8, card)
        + engines
        + ply_table(ours, open3d)
        + throughput_table(http)
    )
    print(text)
    if args.markdown:
        args.markdown.write_text(
            f"# Serving benchmarks\n\nMade by `python bench/serving.py --registry {args.registry} "
            f"--model {args.model} --repeats {r} --markdown {args.markdown}`.\n\n{text}"
        )


if __name__ == "__main__":
    main()
