"""The generator as it runs on a photo after training: the graph that export writes.

Training runs the generator (``trainer.networks.build_generator``) alone, on frames already at its working scale.
A photo at full size needs more around it, all of it fixed operations that export
into the same ONNX and TorchScript graph, so the service runs them with no code of
its own:

1. average-pool the photo by ``work_scale`` (a 640x480 photo costs what a 320x240 one does);
2. the generator;
3. the inference settings' refinements (``contract.spec.InferenceSettings``), at the
   working scale, guided by the pooled photo: that is the grid the network blurs on,
   and a quarter of the pixels at work_scale 2;
4. bilinear upsampling back to the photo's size.

A new inference setting is a field in ``InferenceSettings`` and its step here.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from contract.runtime import from_grid, to_grid
from contract.spec import InferenceSettings
from trainer.refine import ColourWeightedMedian


class InferenceGraph(nn.Module):
    """Photo in ([-1, 1], N x 3 x H x W, H and W multiples of ``input_multiple``), tanh depth out at its size.

    The refinements have no weights, so the state dict is the generator's under ``generator.``.
    """

    def __init__(self, generator: nn.Module, settings: InferenceSettings):
        super().__init__()
        self.generator = generator
        self.settings = settings
        self.work_scale = generator.spec.work_scale  # a plain int, so TorchScript can read it
        self.input_multiple = generator.spec.input_multiple
        self.median = ColourWeightedMedian(settings.median_radius, settings.median_sigma, settings.median_spacing)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        k = self.work_scale
        if k == 1:
            return self.median(self.generator(x), x)
        small = F.avg_pool2d(x, k)
        depth = self.median(self.generator(small), small)
        return F.interpolate(depth, scale_factor=float(k), mode="bilinear", align_corners=False)


class EagerGenerator:
    """A torch module (an ``InferenceGraph``, or a loaded TorchScript file) as an ``ExportedGenerator``.

    Validation, evaluation of checkpoints and the export's parity check run through it,
    on whatever device the module lives on.
    """

    def __init__(self, module: nn.Module, multiple: int):
        self.module = module
        self.multiple = multiple

    def predict_raw(self, rgb: np.ndarray, *, once: bool = False) -> np.ndarray:
        x = torch.from_numpy(to_grid(rgb, self.multiple))
        device = next(self.module.parameters()).device
        with torch.inference_mode():
            y = self.module(x.to(device))
        return from_grid(y.float().cpu().numpy(), *rgb.shape[:2])
