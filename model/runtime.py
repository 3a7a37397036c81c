"""Run an exported generator on one image: ONNX Runtime, or TorchScript.

Both share one contract (``ExportedGenerator``): HxWx3 uint8 in, HxW float32 of
the generator's tanh output back, at the input's size. Padding to the
generator's grid and cropping back happen here, once, for every caller: the
export parity check, evaluation of a published version, and the service.

The ONNX path imports no torch; TorchScript imports it only when constructed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from model.codec import rgb_to_input
from model.geometry import pad_to_multiple


class ExportedGenerator(Protocol):
    multiple: int

    def predict_raw(self, rgb: np.ndarray) -> np.ndarray: ...


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
        h, w = rgb.shape[:2]
        x = rgb_to_input(pad_to_multiple(rgb, self.multiple))
        (y,) = self.session.run(None, {self.input_name: x})
        return np.ascontiguousarray(y[0, 0, :h, :w], dtype=np.float32)


class TorchScriptGenerator:
    """A TorchScript generator (needs the ``train`` extra, which brings torch)."""

    def __init__(self, path: Path, multiple: int, threads: int = 0):
        import torch

        if threads:
            torch.set_num_threads(threads)
        self._torch = torch
        self.module = torch.jit.load(str(path), map_location="cpu").eval()
        self.multiple = multiple

    def predict_raw(self, rgb: np.ndarray) -> np.ndarray:
        h, w = rgb.shape[:2]
        x = self._torch.from_numpy(rgb_to_input(pad_to_multiple(rgb, self.multiple)))
        with self._torch.inference_mode():
            y = self.module(x)
        return y[0, 0, :h, :w].numpy().astype(np.float32)
