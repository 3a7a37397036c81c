"""Eager-PyTorch prediction of metric depth for one image, at the image's own size."""

from __future__ import annotations

import numpy as np
import torch

from model.codec import DepthEncoding, rgb_to_input
from model.geometry import pad_to_multiple
from model.networks import GlobalGenerator


@torch.no_grad()
def predict_raw(generator: GlobalGenerator, rgb: np.ndarray) -> np.ndarray:
    """Generator output (tanh range) for an HxWx3 uint8 image, as HxW float32.

    The image is reflection-padded to the generator's grid and the output is
    cropped back, so any input size comes back at that size.
    """
    h, w = rgb.shape[:2]
    x = torch.from_numpy(rgb_to_input(pad_to_multiple(rgb, generator.config.input_multiple)))
    device = next(generator.parameters()).device
    y = generator(x.to(device))
    return y[0, 0, :h, :w].float().cpu().numpy()


def predict_depth(generator: GlobalGenerator, rgb: np.ndarray, encoding: DepthEncoding) -> np.ndarray:
    """Metric depth (metres, HxW float32) for an HxWx3 uint8 image."""
    return encoding.decode(predict_raw(generator, rgb))
