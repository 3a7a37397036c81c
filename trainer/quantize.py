"""An int8 copy of an exported generator: ONNX Runtime's static quantisation, calibrated on the model's own frames.

Why static QDQ: the fp32 graph already runs at the CPU's fp32 peak, so only fewer bits
make it faster. Dynamic quantisation measures every activation's range at run time, which
costs more than it saves on a convolutional generator; static QDQ with per-channel int8
weights and uint8 activations lets ONNX Runtime fuse each convolution into an integer one
(VNNI where the CPU has it).

Calibration sees the frames the model was trained on, at the size the service feeds it
(the card's camera): activation ranges from other scenes would clip this model's. What
``export --precision int8`` uses was chosen by measurement (``bench/int8.py``, the table in
docs/research.md): the percentile calibration, which ignores the rare extreme activations
that stretch a min-max range, was the one change that mattered (0.012 δ1 on the kitchen).
Leaving the first and last convolutions in fp32, or quantising the convolutions alone,
moved δ1 by 0.001 and speed not measurably, so every node ONNX Runtime can quantise is.
"""

from __future__ import annotations

import contextlib
import io
import logging
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx

from contract.codec import DepthEncoding
from contract.geometry import Intrinsics
from contract.resample import inference_max_pixels, to_model_camera
from contract.runtime import OnnxGenerator, depth_agreement, to_grid
from recordings.frames import FrameReader

#: ONNX Runtime's calibration methods, by the names the card and the command line use.
METHODS = ("minmax", "entropy", "percentile")
#: What ``export --precision int8`` makes: the calibration, how many training frames it sees, the nodes
#: left in fp32 and the kinds of node quantised (chosen with bench/int8.py).
CALIBRATION = "percentile"
CALIBRATION_FRAMES = 20
FP32_NODES = "none"
QUANTISED_OPS = "all"
#: Weights in 7 bits: x86 CPUs without VNNI multiply uint8 activations by int8 weights with VPMADDUBSW, whose
#: 16-bit pair sums saturate (255 x 127 x 2 > 32,767); with ONNX Runtime's reduced range (|w| <= 64) they
#: cannot (255 x 64 x 2 = 32,640), so the graph gives the same depth on every x86 CPU. Its cost on this VNNI
#: CPU is in docs/research.md.
REDUCE_RANGE = True
#: Which nodes can stay in fp32 (``fp32_nodes``).
KEEP = ("none", "ends", "ends+upsampling")
#: Which kinds of node are quantised: every kind ONNX Runtime can (None), or the convolutions alone.
OPS: dict[str, list[str] | None] = {"all": None, "convolutions": ["Conv", "ConvTranspose"]}
#: Convolution kinds: the ends of the graph are the first and last of these.
CONVOLUTIONS = ("Conv", "ConvTranspose")


@dataclass(frozen=True)
class Quantized:
    """What ``quantize_generator`` did: the method, the frames it saw, and the nodes left in fp32."""

    method: str
    frames: int
    fp32_nodes: list[str]


def fp32_nodes(model: onnx.ModelProto, keep: str) -> list[str]:
    """The nodes ``keep`` names, left in fp32 (graph order is topological in an exported file).

    ``none``; ``ends``: the first and last convolutions; ``ends+upsampling``: those and the
    transposed convolutions that upsample the decoder.
    """
    convolutions = [node for node in model.graph.node if node.op_type in CONVOLUTIONS]
    if keep not in KEEP:
        raise ValueError(f"fp32 nodes {keep!r}: expected one of {', '.join(KEEP)}")
    if keep == "none" or not convolutions:
        return []
    kept = {convolutions[0].name, convolutions[-1].name}
    if keep == "ends+upsampling":
        kept |= {node.name for node in convolutions if node.op_type == "ConvTranspose"}
    return sorted(kept)


class _Frames:
    """ONNX Runtime's calibration reader over photos, fed exactly as the service feeds the generator."""

    def __init__(self, input_name: str, frames: Sequence[np.ndarray], multiple: int):
        self._batches: Iterator[dict[str, np.ndarray]] = ({input_name: to_grid(rgb, multiple)} for rgb in frames)

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._batches, None)


def calibration_frames(readers: Sequence[FrameReader], count: int, camera: Intrinsics) -> list[np.ndarray]:
    """``count`` photos spread evenly over every frame of ``readers`` (a model's training sources), each
    resampled to the model's ``camera`` by the one rescale rule, exactly as the service shows it photos."""
    frames = [(reader, i) for reader in readers for i in range(len(reader))]
    picks = np.linspace(0, len(frames) - 1, min(count, len(frames))).round().astype(int)
    photos, max_pixels = [], inference_max_pixels()
    for pick in picks:
        reader, index = frames[pick]
        frame = reader[index]
        photos.append(to_model_camera(frame.rgb, frame.intrinsics, camera, max_pixels)[0])
    return photos


@contextlib.contextmanager
def _quiet_root_logger() -> Iterator[None]:
    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.ERROR)
    try:
        yield
    finally:
        root.setLevel(level)


def quantize_generator(
    fp32: Path,
    out: Path,
    frames: Sequence[np.ndarray],
    multiple: int,
    method: str,
    keep: str,
    ops: str = "all",
    reduce_range: bool = REDUCE_RANGE,
) -> Quantized:
    """Write the int8 QDQ graph of ``fp32`` to ``out``, calibrated on ``frames`` (HxWx3 uint8 at the input size).

    ``keep`` names the nodes left in fp32 (``fp32_nodes``); ``ops`` the kinds of node quantised
    (``OPS``: every kind ONNX Runtime can, or the convolutions alone, leaving the residual sums fp32);
    ``reduce_range`` quantises weights to 7 bits (``REDUCE_RANGE``).
    """
    from onnxruntime.quantization import (
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quant_pre_process,
        quantize_static,
    )

    if method not in METHODS:
        raise ValueError(f"calibration method {method!r}: expected one of {', '.join(METHODS)}")
    if not frames:
        raise ValueError("no calibration frames")
    calibrate = {
        "minmax": CalibrationMethod.MinMax,
        "entropy": CalibrationMethod.Entropy,
        "percentile": CalibrationMethod.Percentile,
    }[method]
    with tempfile.TemporaryDirectory() as tmp:
        prepared = Path(tmp) / "prepared.onnx"
        quant_pre_process(str(fp32), str(prepared), skip_symbolic_shape=True)
        model = onnx.load(str(prepared))
        kept = fp32_nodes(model, keep)
        reader = _Frames(model.graph.input[0].name, frames, multiple)
        # ONNX Runtime prints its calibration's progress and logs a warning per 1-D weight it leaves per-tensor.
        with contextlib.redirect_stdout(io.StringIO()), _quiet_root_logger():
            quantize_static(
                str(prepared),
                str(out),
                reader,
                quant_format=QuantFormat.QDQ,
                per_channel=True,
                weight_type=QuantType.QInt8,
                activation_type=QuantType.QUInt8,
                reduce_range=reduce_range,
                calibrate_method=calibrate,
                nodes_to_exclude=kept,
                op_types_to_quantize=OPS[ops],
            )
    return Quantized(method=method, frames=len(frames), fp32_nodes=kept)


def int8_parity(fp32: Path, int8: Path, image: np.ndarray, multiple: int, encoding: DepthEncoding) -> dict[str, float]:
    """How far the int8 graph's depth is from the fp32 graph's on one photo (``contract.runtime.depth_agreement``)."""
    reference = encoding.decode(OnnxGenerator(fp32, multiple).predict_raw(image))
    depth = encoding.decode(OnnxGenerator(int8, multiple).predict_raw(image))
    return depth_agreement(reference, depth)
