"""The optional TorchScript engine (``RGB2CLOUD_ENGINE=torchscript``): needs the ``train`` extra.

Kept apart from the rest of the service, which never imports torch: ``app.loading``
imports this module only when the backend is asked for.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from contract.runtime import from_grid, to_grid


class TorchScriptGenerator:
    """A TorchScript file on the CPU, run as ``contract.runtime.ExportedGenerator``."""

    def __init__(self, path: Path, multiple: int, threads: int = 0):
        if threads:
            torch.set_num_threads(threads)
        self.module = torch.jit.load(str(path), map_location="cpu").eval()
        self.multiple = multiple

    def predict_raw(self, rgb: np.ndarray, *, once: bool = False) -> np.ndarray:
        with torch.inference_mode():
            y = self.module(torch.from_numpy(to_grid(rgb, self.multiple)))
        return from_grid(y.numpy(), *rgb.shape[:2])


def weight_shapes(path: Path) -> list[tuple[int, ...]]:
    """The shape of every 4-D weight stored in a TorchScript file."""
    module = torch.jit.load(str(path), map_location="cpu")
    return [tuple(t.shape) for t in module.state_dict().values() if t.dim() == 4]
