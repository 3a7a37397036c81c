"""Export the generator (ONNX + TorchScript), prove parity, publish a versioned card.

What is exported is the ``InferenceGraph`` (the generator with its working scale and
refinements), never a training wrapper: input ``rgb`` (N, 3, H, W) in [-1, 1] with
dynamic N, H and W (multiples of the spec's ``input_multiple``), output ``depth``
(N, 1, H, W) in tanh range. Padding, cropping and metres live in ``contract.runtime``
and ``contract.codec``, shared with the service.
"""

from __future__ import annotations

import json
import logging
import subprocess
import tempfile
import warnings
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image

from contract.card import (
    INT8_ONNX_FILE,
    ONNX_FILE,
    SAMPLE_FILE,
    TORCHSCRIPT_FILE,
    WEIGHTS_FILE,
    DataRef,
    FitRecord,
    Int8Graph,
    Metrics,
    ModelCard,
    Training,
    publish,
)
from contract.codec import INPUT_ENCODING, DepthEncoding
from contract.errors import UserError
from contract.geometry import Intrinsics
from contract.resample import to_model_camera
from contract.runtime import OnnxGenerator, Precision, check_sizes, disagreement, worst_agreement
from recordings.frames import FrameReader
from trainer.checkpoint import load_graph
from trainer.config import DataSource, RunConfig
from trainer.data.sources import describe, open_source
from trainer.efficientnet import imagenet_lineage
from trainer.inference import EagerGenerator, InferenceGraph
from trainer.quantize import (
    CALIBRATION,
    CALIBRATION_FRAMES,
    FP32_NODES,
    QUANTISED_OPS,
    calibration_frames,
    int8_parity,
    quantize_generator,
)

PARITY_TOLERANCE = 1e-4
OPSET = 18


class ParityError(ValueError):
    """An exported file disagrees with eager PyTorch beyond the tolerance."""


def export_onnx(graph: InferenceGraph, path: Path) -> None:
    """One self-contained .onnx file with dynamic batch, height and width."""
    m = graph.input_multiple
    example = torch.zeros(1, graph.generator.spec.input_nc, 2 * m, 3 * m)
    dynamic = torch.export.Dim.DYNAMIC
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            graph.eval(),
            (example,),
            str(path),
            dynamo=True,
            external_data=False,
            input_names=["rgb"],
            output_names=["depth"],
            opset_version=OPSET,
            dynamic_shapes={"x": {0: dynamic, 2: dynamic, 3: dynamic}},
            verbose=False,
        )


def export_torchscript(graph: InferenceGraph, path: Path) -> None:
    torch.jit.script(graph.eval()).save(str(path))


def export_weights(graph: InferenceGraph, path: Path) -> None:
    """The generator's own state (BatchNorm unfolded), in safetensors: what ``fit --from`` and
    ``train.start_from`` read, under any torch, where a TorchScript file names the operators of the
    torch that wrote it."""
    from safetensors.torch import save_file

    save_file({key: tensor.contiguous() for key, tensor in graph.generator.state_dict().items()}, str(path))


def parity_sizes(height: int, width: int, multiple: int) -> list[tuple[int, int]]:
    """The image's own size plus one that is not a multiple of the grid."""
    odd = (height * 3 // 4) | 1, (width * 3 // 4) | 1
    if odd[0] % multiple == 0 or odd[1] % multiple == 0:
        odd = odd[0] + 2, odd[1] + 2
    return [(height, width), odd]


def check_parity(graph: InferenceGraph, folder: Path, image: np.ndarray) -> dict[str, float]:
    """Max abs difference of each exported file vs eager PyTorch, at two sizes.

    Raises ``ParityError`` if any differs by more than ``PARITY_TOLERANCE`` or
    returns an output whose size is not the input's.
    """
    m = graph.input_multiple
    runners = {
        "onnx": OnnxGenerator(folder / ONNX_FILE, m),
        "torchscript": EagerGenerator(torch.jit.load(str(folder / TORCHSCRIPT_FILE), map_location="cpu").eval(), m),
    }
    reference = EagerGenerator(graph.eval(), m)
    report = {}
    for h, w in parity_sizes(image.shape[0], image.shape[1], m):
        rgb = np.asarray(Image.fromarray(image).resize((w, h), Image.Resampling.BILINEAR))
        eager = reference.predict_raw(rgb)
        for name, runner in runners.items():
            out = runner.predict_raw(rgb)
            if out.shape != (h, w):
                raise ParityError(f"{name} returned {out.shape[1]}x{out.shape[0]} for a {w}x{h} input")
            diff = float(np.abs(out - eager).max())
            report[f"{name}@{w}x{h}"] = diff
            if diff > PARITY_TOLERANCE:
                raise ParityError(f"{name} differs from eager PyTorch by {diff:.2e} at {w}x{h} (> {PARITY_TOLERANCE})")
    return report


def publish_int8(
    folder: Path,
    sources: Sequence[DataSource],
    readers: Sequence[FrameReader],
    camera: Intrinsics,
    shown: np.ndarray,
    multiple: int,
    encoding: DepthEncoding,
) -> Int8Graph:
    """Quantise ``folder``'s fp32 graph into ``INT8_ONNX_FILE`` beside it, check it, and describe it for the card.

    Calibration: ``CALIBRATION_FRAMES`` of the training frames, spread over them, at the card camera's
    size; ``shown`` is the version's sample (the parity image at that size, as the service shows photos),
    which wherever the version loads both graphs are compared on again.
    """
    photos = calibration_frames(readers, CALIBRATION_FRAMES, camera)
    int8 = folder / INT8_ONNX_FILE
    done = quantize_generator(folder / ONNX_FILE, int8, photos, multiple, CALIBRATION, FP32_NODES, QUANTISED_OPS)
    graphs = folder / ONNX_FILE, folder / INT8_ONNX_FILE
    parity = worst_agreement([int8_parity(*graphs, photo, multiple, encoding) for photo in check_sizes(shown)])
    if (why := disagreement(parity)) is not None:
        raise UserError(
            f"{INT8_ONNX_FILE}: int8 depth is not fp32's on the parity image ({why}): this model does not keep its "
            "depth in int8; publish it without --precision int8"
        )
    return Int8Graph(
        method="ONNX Runtime static QDQ: per-channel int8 weights in 7 bits (reduce_range: no saturation on CPUs "
        "without VNNI), uint8 activations",
        calibration=done.method,
        frames=done.frames,
        frames_from=[describe(source) for source in sources],
        fp32_nodes=done.fp32_nodes,
        parity=parity,
    )


def trainer_commit() -> str:
    """The git commit of this code, with '-dirty' when it has uncommitted changes."""
    here = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return commit + ("-dirty" if dirty else "")


def metrics_from_report(path: Path) -> Metrics:
    """The card's metrics entry from an ``evaluate`` metrics.json."""
    report = json.loads(Path(path).read_text())
    range_m = tuple(report["depth_range_m"])
    return Metrics.from_result(report["metrics"], report["split"], range_m, report.get("read_at_colour_camera"))


def _data_ref(source: DataSource, reader: FrameReader) -> DataRef:
    """The card's entry for one training source; a source without a licence cannot be published."""
    if not reader.licence:
        raise UserError(f"training source {source.root} has no licence: set 'licence' in its data entry")
    return DataRef(
        name=describe(source), format=source.format, frames=source.frames or source.split, licence=reader.licence
    )


def encoder_lineage(config: RunConfig) -> list[DataRef]:
    """ImageNet's entry when the generator's encoder started from its weights, directly or through
    ``train.start_from`` (a start's lineage is not read back here, so any start counts: a licence is
    better named once too often than lost)."""
    pretrained = config.generator.encoder != "pix2pixhd"
    if not pretrained or (config.train.encoder_weights == "random" and config.train.start_from is None):
        return []
    return [imagenet_lineage()]


def export_and_publish(
    checkpoint: Path,
    registry: Path,
    name: str,
    version: str,
    metrics: list[Metrics],
    parity_image: Path,
    inference: dict[str, Any] | None = None,
    *,
    data: list[DataRef] | None = None,
    fit: FitRecord | None = None,
    precision: Precision = "fp32",
) -> Path:
    """Export, check parity, and publish ``<registry>/<name>/<version>/`` with its card.

    ``checkpoint`` is a training checkpoint or a published version folder (its
    weights, published again). ``inference`` changes the inference settings the
    checkpoint's config (or the version's card) has; the settings in use are baked
    into the exported graph and recorded in the card. A card from a published
    version also names it in ``derived_from``. ``data`` replaces the card's data
    entries made from the training sources, and ``fit`` records how ``rgb2cloud fit``
    made the model. ``precision="int8"`` also publishes an int8 graph beside the fp32 one
    (``trainer.quantize``), calibrated on the training frames.
    """
    target = Path(registry) / name / version
    if target.exists():
        raise FileExistsError(f"{target} already exists: versions are immutable, publish a new one")
    graph, weights = load_graph(checkpoint, inference)
    config = weights.config
    readers = [open_source(s) for s in config.data.train]
    data = data or [_data_ref(source, reader) for source, reader in zip(config.data.train, readers, strict=True)]
    data = data + [ref for ref in encoder_lineage(config) if ref.name not in {d.name for d in data}]
    camera = weights.camera
    with Image.open(parity_image) as im:
        image = np.asarray(im.convert("RGB"))
    # The version's sample: the parity photo at the card camera's size, as the service shows a photo from that
    # camera to the generator (every load checks and warms each engine on it there). It has no camera of its own,
    # so it is taken to have the model's field of view.
    at_camera = camera.width * camera.height
    shown, _ = to_model_camera(image, camera.resized(image.shape[1], image.shape[0]), camera, at_camera)

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        export_onnx(graph, folder / ONNX_FILE)
        export_torchscript(graph, folder / TORCHSCRIPT_FILE)
        export_weights(graph, folder / WEIGHTS_FILE)
        parity = check_parity(graph, folder, image)
        Image.fromarray(shown).save(folder / SAMPLE_FILE)
        files = {name: folder / name for name in (ONNX_FILE, TORCHSCRIPT_FILE, WEIGHTS_FILE, SAMPLE_FILE)}
        int8 = None
        if precision == "int8":
            int8 = publish_int8(folder, config.data.train, readers, camera, shown, graph.input_multiple, config.depth)
            files[INT8_ONNX_FILE] = folder / INT8_ONNX_FILE
        card = ModelCard(
            name=name,
            version=version,
            created=datetime.now(UTC),
            files={},
            generator=config.generator,
            inference=config.inference,
            input_multiple=config.generator.input_multiple,
            input_encoding=INPUT_ENCODING,
            depth_encoding=config.depth,
            camera=camera,
            training=Training(
                data=data,
                steps=weights.step,
                duration_s=round(weights.train_seconds, 1),
                hardware=weights.hardware,
                config=config.model_dump(mode="json", exclude={"inference"}),
                fit=fit,
            ),
            metrics=metrics,
            trainer_commit=trainer_commit(),
            parity=parity,
            int8=int8,
            sample=SAMPLE_FILE,
            derived_from=weights.published,
        )
        return publish(registry, card, files)
