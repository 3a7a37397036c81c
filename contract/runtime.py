"""Run an exported generator on one image: the contract every runner keeps, and ONNX Runtime's.

Every runner (``ExportedGenerator``) takes HxWx3 uint8 and gives back HxW float32
of the generator's tanh output, at the input's size. Padding to the generator's
grid and cropping back are ``to_grid`` and ``from_grid`` here, once, for every
runner: ONNX Runtime below, the service's optional TorchScript backend
(``app.torchscript``) and the trainer's eager one (``trainer.inference``).

Torch-free: the service's default install has no torch.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Protocol

import numpy as np

from contract.codec import rgb_to_input
from contract.geometry import pad_to_multiple

#: The graphs a version can ship: fp32 always, int8 beside it when exported with ``--precision int8``.
Precision = Literal["fp32", "int8"]
#: How a generator runs: a graph at its own precision, or the fp32 graph on the CPU's bf16 units (OpenVINO).
RunPrecision = Literal["fp32", "bf16", "int8"]
#: The share of pixels whose reduced-precision depth (int8, bf16) must be within 1.25x of the fp32 depth (δ1
#: with fp32 as the truth): at export on the parity photo, and again wherever a version loads, on the sample
#: it ships, before that precision is served there.
PARITY_AGREEMENT = 0.95


def depth_agreement(reference: np.ndarray, depth: np.ndarray) -> dict[str, float]:
    """How far reduced-precision depth is from fp32 depth: ``agreement`` (the share within 1.25x) and ``median_rel``."""
    valid = (reference > 0) & (depth > 0)
    if not valid.any():
        return {"agreement": 0.0, "median_rel": 1.0}
    ratio = np.maximum(depth[valid] / reference[valid], reference[valid] / depth[valid])
    median_rel = float(np.median(np.abs(depth[valid] - reference[valid]) / reference[valid]))
    return {"agreement": float((ratio < 1.25).mean()), "median_rel": median_rel}


class ExportedGenerator(Protocol):
    multiple: int

    def predict_raw(self, rgb: np.ndarray) -> np.ndarray: ...


def to_grid(rgb: np.ndarray, multiple: int) -> np.ndarray:
    """HxWx3 uint8 -> the generator's (1, 3, H', W') input, padded to a multiple of ``multiple``."""
    return rgb_to_input(pad_to_multiple(rgb, multiple))


def from_grid(output: np.ndarray, height: int, width: int) -> np.ndarray:
    """The generator's (1, 1, H', W') output cropped back to the photo's HxW, float32."""
    return np.ascontiguousarray(output[0, 0, :height, :width], dtype=np.float32)


class OnnxGenerator:
    """ONNX Runtime on the CPU with a fixed thread count (the service sizes it to its cores)."""

    def __init__(self, path: Path, multiple: int, threads: int = 0):
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name
        self.multiple = multiple

    def predict_raw(self, rgb: np.ndarray) -> np.ndarray:
        (y,) = self.session.run(None, {self.input_name: to_grid(rgb, self.multiple)})
        return from_grid(y, *rgb.shape[:2])
