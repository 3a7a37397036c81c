"""Verify and warm one published version for serving. Every failure names the file and the reason."""

from __future__ import annotations

import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

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
from contract.runtime import INT8_AGREEMENT, ExportedGenerator, OnnxGenerator, Precision, int8_agreement


class ModelLoadError(Exception):
    """The configured model cannot be served; the message is the one log line to print."""


@dataclass
class LoadedModel:
    card: ModelCard
    path: Path
    #: A runner per precision the version ships for this backend: always fp32, and int8 with ONNX Runtime when
    #: the card lists an int8 graph.
    generators: dict[Precision, ExportedGenerator]
    warmup_seconds: float
    #: The size of the weights files the runtimes hold: what /metrics counts per loaded model.
    weights_bytes: int
    #: Why a precision is not served by this version: the graph is not there (or not for this backend), or
    #: it is there and disagrees with fp32 on this machine (``disagrees``, which a request asking for it
    #: explicitly gets as 409).
    unserved: dict[Precision, str] = field(default_factory=dict)
    disagrees: set[Precision] = field(default_factory=set)
    #: One generator call at a time: it already uses every inference thread, while the
    #: other pool workers decode and encode around it.
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def label(self) -> str:
        """``NAME:VERSION``, as requests name it and /metrics labels it."""
        return f"{self.card.name}:{self.card.version}"

    def serving(self, wanted: Precision) -> Precision:
        """The precision a request that wants ``wanted`` gets: that one if this version ships it, else fp32."""
        return wanted if wanted in self.generators else "fp32"

    def predict_depth(self, rgb: np.ndarray, precision: Precision = "fp32") -> np.ndarray:
        """Metres, HxW float32, for an HxWx3 uint8 image (padded to the grid and cropped back).

        ``precision`` must be one this version ships (``serving`` picks it).
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


def load_version(folder: Path, settings: Settings) -> LoadedModel:
    """Verify (sha256, the card's input and output, config vs weights), build the runtimes and warm them up.

    The int8 graph is loaded beside the fp32 one when the card lists it and the backend is ONNX Runtime, so
    a request can ask for either; every file is verified whichever the settings prefer.
    """
    try:
        card = load_card(folder)
        verify_files(folder, card)
    except CardError as e:
        raise ModelLoadError(str(e)) from e
    check_contract(card, folder)
    file_name = ONNX_FILE if settings.backend == "onnx" else TORCHSCRIPT_FILE
    if file_name not in card.files:
        raise ModelLoadError(f"{folder / file_name}: the card lists no such file for backend {settings.backend!r}")
    paths: dict[Precision, Path] = {"fp32": folder / file_name}
    unserved: dict[Precision, str] = {}
    if card.int8 is None:
        unserved["int8"] = "this version has no int8 graph"
    elif settings.backend != "onnx":
        unserved["int8"] = f"the {settings.backend} backend runs the fp32 graph only"
    else:
        paths["int8"] = folder / card.int8.file
    generators = {precision: _runner(path, card, settings) for precision, path in paths.items()}
    weights_bytes = sum(path.stat().st_size for path in paths.values())
    model = LoadedModel(card, folder, generators, 0.0, weights_bytes, unserved)
    start = time.perf_counter()
    # The warm-up photo is the int8 sample where the version ships one (it is at the card camera's size), so
    # the warm-up's depths are also the int8 check's.
    sample = _int8_sample(folder, card)
    photo = sample if sample is not None else np.zeros((card.camera.height, card.camera.width, 3), np.uint8)
    warm = {precision: model.predict_depth(photo, precision) for precision in paths}
    for precision, depth in warm.items():
        if depth.shape != (card.camera.height, card.camera.width):
            raise ModelLoadError(
                f"{paths[precision]}: warm-up returned {depth.shape} for a {card.camera.width}x{card.camera.height} "
                "input"
            )
    model.warmup_seconds = time.perf_counter() - start
    if "int8" in warm and sample is not None and (why := _int8_disagreement(card, warm)):
        del model.generators["int8"]
        model.unserved["int8"] = why
        model.disagrees.add("int8")
    return model


def _int8_sample(folder: Path, card: ModelCard) -> np.ndarray | None:
    """The photo the version's int8 and fp32 depth are compared on (None for versions published without one)."""
    if card.int8 is None or card.int8.sample is None:
        return None
    with Image.open(folder / card.int8.sample) as im:
        return np.asarray(im.convert("RGB"))


def _int8_disagreement(card: ModelCard, depth: dict[Precision, np.ndarray]) -> str | None:
    """Why the int8 graph may not be served here: its depth on the version's sample photo is not fp32's.

    Export checked the two on the exporting machine; integer arithmetic differs between CPUs (saturation
    without VNNI), so every machine that loads the version checks again before serving int8.
    """
    parity = int8_agreement(depth["fp32"], depth["int8"])
    if card.int8 is None or parity["agreement"] >= INT8_AGREEMENT:
        return None
    return (
        f"its int8 graph disagrees with fp32 on this machine: within 1.25x on {parity['agreement']:.1%} of the "
        f"sample's pixels ({card.int8.parity['agreement']:.1%} at export, {INT8_AGREEMENT:.0%} needed)"
    )


def _runner(path: Path, card: ModelCard, settings: Settings) -> ExportedGenerator:
    """One file's runtime, after checking that its convolutions are the card's generator's."""
    check_weights(card, path, settings.backend)
    try:
        if settings.backend == "onnx":
            return OnnxGenerator(path, card.input_multiple, settings.threads)
        from app.torchscript import TorchScriptGenerator

        return TorchScriptGenerator(path, card.input_multiple, settings.threads)
    except Exception as e:  # the runtime's own parse errors
        raise ModelLoadError(f"{path}: the {settings.backend} runtime cannot load it: {e}") from e
