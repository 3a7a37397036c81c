"""Run a generator on one image: ONNX Runtime, TorchScript, or an eager torch module.

All share one contract (``ExportedGenerator``): HxWx3 uint8 in, HxW float32 of
the generator's tanh output back, at the input's size. Padding to the
generator's grid and cropping back happen here, once, for every caller: the
trainer's validation, evaluation, the export parity check and the service.

The ONNX path imports no torch; the torch runners import it only when constructed.
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


class TorchModuleGenerator:
    """A torch module (eager ``GlobalGenerator`` or TorchScript) on whatever device it lives on."""

    def __init__(self, module, multiple: int):
        import torch

        self._torch = torch
        self.module = module
        self.multiple = multiple

    def predict_raw(self, rgb: np.ndarray) -> np.ndarray:
        h, w = rgb.shape[:2]
        x = self._torch.from_numpy(rgb_to_input(pad_to_multiple(rgb, self.multiple)))
        device = next(self.module.parameters()).device
        with self._torch.inference_mode():
            y = self.module(x.to(device))
        return y[0, 0, :h, :w].float().cpu().numpy()


class TorchScriptGenerator(TorchModuleGenerator):
    """A TorchScript file on the CPU (needs the ``train`` extra, which brings torch)."""

    def __init__(self, path: Path, multiple: int, threads: int = 0):
        import torch

        if threads:
            torch.set_num_threads(threads)
        super().__init__(torch.jit.load(str(path), map_location="cpu").eval(), multiple)
