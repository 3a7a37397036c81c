"""Verify and warm one published version for serving. Every failure names the file and the reason."""

from __future__ import annotations

import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from PIL import Image

from app.engine_choice import Timing, fastest, timings
from app.settings import Settings
from contract.card import (
    CARD_FILE,
    ONNX_FILE,
    TORCHSCRIPT_FILE,
    CardError,
    ModelCard,
    load_card,
    verify_files,
)
from contract.codec import INPUT_ENCODING
from contract.engines import Engine, onnx_runner, runs
from contract.runtime import (
    ExportedGenerator,
    RunPrecision,
    check_sizes,
    depth_agreement,
    disagreement,
    worst_agreement,
)


class ModelLoadError(Exception):
    """The configured model cannot be served; the message is the one log line to print."""


@dataclass
class LoadedModel:
    card: ModelCard
    path: Path
    #: A runner per precision this version serves here, each on the engine that won it (``engines``): always
    #: fp32; bf16 where the CPU has bf16 units and it passed its check; int8 where the card lists a graph and
    #: it passed its check.
    generators: dict[RunPrecision, ExportedGenerator]
    engines: dict[RunPrecision, Engine]
    #: What requests without precision= (or with ``auto``) get: bf16 where it is served and faster, else fp32.
    auto: RunPrecision
    warmup_seconds: float
    #: The size of the weights files the runtimes hold: what /metrics counts per loaded model.
    weights_bytes: int
    #: Why a precision is not served here: no graph, an engine or CPU that cannot run it, slower than fp32
    #: (bf16), or a check it failed (``disagrees``, which a request asking for it explicitly gets as 409).
    unserved: dict[RunPrecision, str] = field(default_factory=dict)
    disagrees: set[RunPrecision] = field(default_factory=set)
    #: Each candidate's timed runs on the check photo at load, by ``ENGINE PRECISION`` (``openvino fp32``).
    measured: dict[str, Timing] = field(default_factory=dict)
    #: Why each precision runs on its engine, where more than one engine could run it: the timings it was
    #: chosen on and by how much (``app.engine_choice.fastest``).
    chosen: dict[RunPrecision, str] = field(default_factory=dict)
    #: Why a candidate was left out where another engine serves its precision (``openvino int8``: its int8 graph
    #: disagrees with fp32 on this machine ...): what a precision ``unserved`` would have said, per engine.
    dropped: dict[str, str] = field(default_factory=dict)
    #: One generator call at a time: it already uses every inference thread, while the
    #: other pool workers decode and encode around it.
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def label(self) -> str:
        """``NAME:VERSION``, as requests name it and /metrics labels it."""
        return f"{self.card.name}:{self.card.version}"

    def serving(self, wanted: RunPrecision | Literal["auto"]) -> RunPrecision:
        """The precision a request that wants ``wanted`` gets: that one if served here, ``auto``'s, else fp32."""
        if wanted == "auto":
            return self.auto
        return wanted if wanted in self.generators else "fp32"

    def predict_depth(self, rgb: np.ndarray, precision: RunPrecision = "fp32") -> np.ndarray:
        """Metres, HxW float32, for an HxWx3 uint8 image (padded to the grid and cropped back).

        ``precision`` must be one this version serves (``serving`` picks it).
        """
        with self.lock:
            raw = self.generators[precision].predict_raw(rgb)
        return self.card.depth_encoding.decode(raw)


def file_weight_shapes(path: Path, backend: str) -> list[tuple[int, ...]]:
    """The shape of every 4-D weight (convolutions, 1x1 ones included) stored in an exported file."""
    if backend == "onnx":
        import onnx

        graph = onnx.load(str(path), load_external_data=False).graph
        return [tuple(t.dims) for t in graph.initializer if len(t.dims) == 4]
    from app.torchscript import weight_shapes

    return weight_shapes(path)


def check_weights(card: ModelCard, path: Path, backend: str) -> None:
    """The card's generator config must describe exactly the convolutions in the file."""
    expected = Counter(card.generator.weight_shapes())
    actual = Counter(file_weight_shapes(path, backend))
    if expected != actual:
        missing, extra = expected - actual, actual - expected
        raise ModelLoadError(
            f"{path}: weights do not match the card's generator config {card.generator.model_dump()} "
            f"(missing {dict(missing)}, unexpected {dict(extra)})"
        )


def check_contract(card: ModelCard, folder: Path) -> None:
    """The card's input and output must be what this service feeds and reads, or every answer would be wrong.

    The service feeds ``contract.codec.INPUT_ENCODING``, padded to the card's ``input_multiple``,
    and reads one channel decoded by the card's ``depth_encoding``.
    """
    path = folder / CARD_FILE
    if card.input_encoding != INPUT_ENCODING:
        raise ModelLoadError(
            f"{path}: input_encoding {card.input_encoding!r}; this service feeds {INPUT_ENCODING!r} only"
        )
    if card.input_multiple != card.generator.input_multiple:
        raise ModelLoadError(
            f"{path}: input_multiple {card.input_multiple}, but its generator needs multiples of "
            f"{card.generator.input_multiple}"
        )
    if (card.generator.input_nc, card.generator.output_nc) != (3, 1):
        raise ModelLoadError(
            f"{path}: a generator of {card.generator.input_nc} input and {card.generator.output_nc} output "
            "channels; this service feeds RGB and reads one depth channel"
        )
    if card.int8 is not None and card.int8.file not in card.files:
        raise ModelLoadError(f"{path}: int8 graph {card.int8.file} is not among the card's files and their sha256")


#: The engines each setting of ``RGB2CLOUD_ENGINE`` puts up for every precision.
CANDIDATES: dict[str, tuple[Engine, ...]] = {
    "auto": ("onnxruntime", "openvino"),
    "onnxruntime": ("onnxruntime",),
    "openvino": ("openvino",),
    "torchscript": ("torchscript",),
}


def load_version(folder: Path, settings: Settings) -> LoadedModel:
    """Verify (sha256, the card's input and output, config vs weights), build the runtimes, check and warm them.

    Every precision (fp32, bf16, int8) is put up on each engine the settings allow. Each candidate's depth
    on the check photo (the version's sample, else ``stand_in_photo``) is compared with ONNX Runtime fp32's,
    and one that disagrees is not served; where more than one passes, each is timed there and ONNX Runtime kept
    unless another is faster beyond the timing's noise (``app.engine_choice``; what ``auto`` costs at load: one
    compile and a few runs per candidate). bf16 is served only where the CPU has bf16 units, and only if it beats
    fp32. A version whose fp32 runs nowhere it is allowed to is refused.
    """
    try:
        card = load_card(folder)
        verify_files(folder, card)
    except CardError as e:
        raise ModelLoadError(str(e)) from e
    check_contract(card, folder)
    start = time.perf_counter()
    files = _graph_files(folder, card, settings.engine)
    sample = _sample(folder, card)
    photo = sample if sample is not None else stand_in_photo(card.camera.height, card.camera.width)
    built = _reference(files["fp32"], card, settings)  # held only while fp32's candidates are checked
    try:
        photos = check_sizes(photo)
        references = [card.depth_encoding.decode(r.predict_raw(p, once=True)) for r in built.values() for p in photos]
    except Exception as e:  # a graph that loads but cannot run: refused once, with why, never a 500 per request
        raise ModelLoadError(f"{files['fp32']}: its fp32 graph fails on its check photo: {e}") from e
    # A precision without a file to run: no int8 graph in the card, or an engine that runs fp32 only.
    unserved: dict[RunPrecision, str] = {
        p: "this version has no int8 graph" if p == "int8" and card.int8 is None else runs(settings.engine, p) or ""
        for p in ("bf16", "int8")
        if p not in files
    }
    chosen: dict[RunPrecision, tuple[Engine, ExportedGenerator, float]] = {}
    disagrees: set[RunPrecision] = set()
    measured: dict[str, Timing] = {}
    why_chosen: dict[RunPrecision, str] = {}
    dropped: dict[str, str] = {}
    for precision in ("fp32", "bf16", "int8"):
        if precision not in files:
            continue
        check = (photos, references, sample)
        passed, reasons = _candidates(files[precision], card, settings, precision, check, built)
        built.clear()  # the reference, where fp32 passed on it, lives on in ``passed``
        if not passed:
            why = "; ".join(dict.fromkeys(reasons.values()))
            unserved[precision] = why
            disagrees |= {precision} if "disagrees" in why else set()
            continue
        timed = len(passed) > 1 or precision == "bf16"
        times, failed = timings(passed, photo) if timed else (dict.fromkeys(passed, Timing((0.0,))), {})
        measured |= {f"{engine} {precision}": timing for engine, timing in times.items() if timed}
        if times:
            engine, because = fastest(times)
            chosen[precision] = (engine, passed[engine], times[engine].median)
            why_chosen |= {precision: because} if len(times) > 1 else {}  # a choice between engines, and its times
            dropped |= {f"{other} {precision}": why for other, why in (reasons | failed).items()}
        else:
            unserved[precision] = "; ".join(failed.values())
        del passed  # the engines not chosen go now, not while the next precision's are checked
    if "fp32" not in chosen:
        raise ModelLoadError(f"{files['fp32']}: its fp32 graph cannot be served here: {unserved['fp32']}")
    if "bf16" in chosen:
        chosen, unserved = _bf16_if_faster(chosen, unserved, photo, measured)
    model = LoadedModel(
        card,
        folder,
        {precision: runner for precision, (_, runner, _) in chosen.items()},
        {precision: engine for precision, (engine, _, _) in chosen.items()},
        "bf16" if "bf16" in chosen else "fp32",
        0.0,
        sum(files[precision].stat().st_size for precision in chosen),
        unserved,
        disagrees,
        measured,
        {p: why for p, why in why_chosen.items() if p in chosen},
        dropped,
    )
    _warm_up(model, photo, files)
    model.warmup_seconds = time.perf_counter() - start
    return model


def _warm_up(model: LoadedModel, photo: np.ndarray, files: dict[RunPrecision, Path]) -> None:
    """One run of each served precision on the check photo (the card camera's size): its output must be the
    photo's size."""
    height, width = photo.shape[:2]
    for precision in model.generators:
        depth = model.predict_depth(photo, precision)
        if depth.shape != (height, width):
            raise ModelLoadError(f"{files[precision]}: warm-up returned {depth.shape} for a {width}x{height} input")


def _graph_files(folder: Path, card: ModelCard, engine: str) -> dict[RunPrecision, Path]:
    """The file each precision runs: the fp32 graph (ONNX or, for torchscript, TorchScript) for fp32 and bf16,
    the card's int8 graph for int8; each checked to hold the card's generator."""
    file_name = TORCHSCRIPT_FILE if engine == "torchscript" else ONNX_FILE
    if file_name not in card.files:
        raise ModelLoadError(f"{folder / file_name}: the card lists no such file for engine {engine!r}")
    files: dict[RunPrecision, Path] = {"fp32": folder / file_name}
    if engine != "torchscript":
        files["bf16"] = folder / file_name
        if card.int8 is not None:
            files["int8"] = folder / card.int8.file
    for path in set(files.values()):
        check_weights(card, path, "torchscript" if engine == "torchscript" else "onnx")
    return files


def _reference(path: Path, card: ModelCard, settings: Settings) -> dict[tuple[Engine, RunPrecision], ExportedGenerator]:
    """The runner every other is checked against: ONNX Runtime fp32 (TorchScript on its own engine)."""
    engine: Engine = "torchscript" if settings.engine == "torchscript" else "onnxruntime"
    return {(engine, "fp32"): _runner(engine, path, card, settings, "fp32")}


def _candidates(
    path: Path,
    card: ModelCard,
    settings: Settings,
    precision: RunPrecision,
    check: tuple[list[np.ndarray], list[np.ndarray], np.ndarray | None],
    built: dict[tuple[Engine, RunPrecision], ExportedGenerator],
) -> tuple[dict[Engine, ExportedGenerator], dict[Engine, str]]:
    """The engines that run ``precision`` here with the same depth as fp32's, and why each other one does not.

    ``check`` is the photos (the check photo at its size and at twice it), the reference fp32 depth on each,
    and the version's sample (None without one: then no reduced precision is served, since a made-up photo
    says little of how a real one's depth keeps in fewer bits); ``built`` holds runners already made (the
    reference), which are not made twice.
    A candidate that raises while it is checked is dropped with what it raised.
    """
    photos, references, sample = check
    passed: dict[Engine, ExportedGenerator] = {}
    reasons: dict[Engine, str] = {}
    engines = CANDIDATES[settings.engine]
    for engine in engines:
        if why := runs(engine, precision):
            if not (precision == "bf16" and engine != "openvino" and "openvino" in engines):  # OpenVINO's says it
                reasons[engine] = why
            continue
        if precision != "fp32" and sample is None:
            reasons[engine] = (
                f"this version ships no sample photo to check {precision} against fp32 on (a version exported "
                "from its folder with `rgb2cloud export` ships one)"
            )
            continue
        try:
            runner = built.get((engine, precision)) or _runner(engine, path, card, settings, precision)
        except ModelLoadError as e:
            if len(engines) == 1:
                raise
            reasons[engine] = str(e)  # under auto, one engine that cannot load a graph leaves the other
            continue
        try:
            depths = [card.depth_encoding.decode(runner.predict_raw(p, once=True)) for p in photos]
        except Exception as e:
            reasons[engine] = f"its {precision} run on {engine} fails on the check photo: {e}"
            continue
        parity = worst_agreement([depth_agreement(r, d) for r, d in zip(references, depths, strict=True)])
        if (why := disagreement(parity)) is None:
            passed[engine] = runner
        else:
            what = "graph" if precision == "int8" else "path"
            reasons[engine] = f"its {precision} {what} disagrees with fp32 on this machine ({engine}): {why}"
    return passed, reasons


def _bf16_if_faster(
    chosen: dict[RunPrecision, tuple[Engine, ExportedGenerator, float]],
    unserved: dict[RunPrecision, str],
    photo: np.ndarray,
    measured: dict[str, Timing],
) -> tuple[dict[RunPrecision, tuple[Engine, ExportedGenerator, float]], dict[RunPrecision, str]]:
    """bf16 only where it beats fp32 (timed on the same photo when fp32 was not, and recorded): slower, it is
    refused."""
    engine, runner, fp32_ms = chosen["fp32"]
    if not fp32_ms:
        times, failed = timings({engine: runner}, photo)
        if failed:
            raise ModelLoadError(f"{engine} fp32 fails when timed: {failed[engine]}")
        measured[f"{engine} fp32"] = times[engine]
        fp32_ms = times[engine].median
    bf16_ms = chosen["bf16"][2]
    if bf16_ms < fp32_ms:
        return chosen, unserved
    why = f"bf16 ran {bf16_ms:.1f} ms against fp32's {fp32_ms:.1f} ms ({engine}) here: slower, so not served"
    return {p: c for p, c in chosen.items() if p != "bf16"}, {**unserved, "bf16": why}


def _sample(folder: Path, card: ModelCard) -> np.ndarray | None:
    """The photo every engine and precision is checked against ONNX Runtime fp32 on (None for versions
    published without one)."""
    if card.sample is None:
        return None
    with Image.open(folder / card.sample) as im:
        return np.asarray(im.convert("RGB"))


def stand_in_photo(height: int, width: int) -> np.ndarray:
    """The check photo of a version without a sample: smooth colour at an eighth of the size, the same on every
    load (a seeded generator).

    Not a blank photo: on one, every instance norm divides a constant feature map by its near-zero spread, so
    two engines that agree on every real photo give depth 6% apart (ONNX Runtime and OpenVINO fp32, on each
    bundled version) and a sound engine would be refused. On this texture they agree as on real photos.
    """
    coarse = np.random.default_rng(0).integers(0, 256, (height // 8 + 1, width // 8 + 1, 3), dtype=np.uint8)
    return np.asarray(Image.fromarray(coarse).resize((width, height), Image.Resampling.BICUBIC))


def _runner(
    engine: Engine, path: Path, card: ModelCard, settings: Settings, precision: RunPrecision
) -> ExportedGenerator:
    """One file's runtime on one engine."""
    try:
        if engine != "torchscript":
            return onnx_runner(engine, path, card.input_multiple, settings.threads, precision)
        from app.torchscript import TorchScriptGenerator

        return TorchScriptGenerator(path, card.input_multiple, settings.threads)
    except Exception as e:  # the runtime's own parse errors
        raise ModelLoadError(f"{path}: the {engine} engine cannot load it: {e}") from e
