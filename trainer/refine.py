"""Inference-only refinement of a predicted depth map by the photo it came from.

The generator blurs a depth step over a few pixels, and in the blur every pixel
is neither the near nor the far surface's depth, so it fails delta1 whichever
side it belongs to (on 7-Scenes views a third of the pixels beside a depth step
fail, against under 1% of the rest). The photo is sharp there. A colour-weighted
median (Ma et al., "Constant time weighted median filtering for stereo matching and
beyond", ICCV 2013) gives each pixel the median of the depths around it, each counted by how alike its colour is to the
pixel's own: in the blur, the neighbours that share the pixel's colour lie mostly
on its own side of the edge, so it takes that side's depth. On a smooth surface
the median of a window is about its centre's value, so it changes little there.

The window's depths are sorted by a fixed sorting network (Batcher's odd-even
merge sort) of element-wise min, max and where, not by a sort operator: ONNX
Runtime's TopK is slow on hundreds of thousands of short rows, and element-wise
work is what it runs fastest. Fixed operations also let TorchScript and ONNX
(opset 18) export it inside the generator's graph, so the service runs it with
no code of its own.
"""

import torch
import torch.nn.functional as F
from torch import nn


def sorting_network(n: int) -> list[tuple[int, int]]:
    """Batcher's odd-even merge sort for ``n`` inputs: compare-exchange pairs (low, high), in order.

    Built for the next power of two; a pair that touches an index past ``n`` would
    compare with a padding +inf and never swap, so it is left out.
    """
    size = 1 << max(n - 1, 0).bit_length()
    pairs: list[tuple[int, int]] = []
    p = 1
    while p < size:
        k = p
        while k >= 1:
            for j in range(k % p, size - k, 2 * k):
                for i in range(min(k, size - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return [(a, b) for a, b in pairs if b < n]


class ColourWeightedMedian(nn.Module):
    """Each pixel of a depth map replaced by the colour-weighted median of its window.

    The window is (2 ``radius`` + 1)^2 taps, ``spacing`` pixels apart, so spacing 2
    reaches as far as a window twice as wide at the same cost. A tap q of pixel p
    weighs exp(-|rgb_q - rgb_p|^2 / (2 ``sigma``^2)), so p itself weighs 1; the
    median is the smallest depth whose cumulative weight reaches half the window's.
    Edges are replicated, so every pixel has a full window. Radius 0 is the identity.
    """

    pairs: list[tuple[int, int]]  # class-level, so TorchScript types it even when empty

    def __init__(self, radius: int, sigma: float, spacing: int = 1):
        super().__init__()
        self.radius = radius
        self.spacing = spacing
        self.scale = -0.5 / (sigma * sigma)
        self.pairs = sorting_network((2 * radius + 1) ** 2)

    def forward(self, depth: torch.Tensor, rgb: torch.Tensor) -> torch.Tensor:
        if self.radius == 0:
            return depth
        height, width = depth.shape[2], depth.shape[3]
        reach = self.radius * self.spacing
        pad = [reach, reach, reach, reach]
        depth_pad = F.pad(depth, pad, mode="replicate")
        rgb_pad = F.pad(rgb, pad, mode="replicate")
        values: list[torch.Tensor] = []
        weights: list[torch.Tensor] = []
        for row in range(2 * self.radius + 1):
            for col in range(2 * self.radius + 1):
                y, x = row * self.spacing, col * self.spacing
                values.append(depth_pad[:, :, y : y + height, x : x + width])
                difference = rgb_pad[:, :, y : y + height, x : x + width] - rgb
                weights.append(torch.exp(self.scale * (difference * difference).sum(1, keepdim=True)))
        for low, high in self.pairs:
            a, b = values[low], values[high]
            swap = a > b
            values[low], values[high] = torch.minimum(a, b), torch.maximum(a, b)
            weights[low], weights[high] = (
                torch.where(swap, weights[high], weights[low]),
                torch.where(swap, weights[low], weights[high]),
            )
        cumulative: list[torch.Tensor] = [weights[0]]
        for w in weights[1:]:
            cumulative.append(cumulative[-1] + w)
        half = 0.5 * cumulative[-1]
        median = values[-1]
        for i in range(len(values) - 2, -1, -1):  # downwards, so the smallest qualifying depth wins
            median = torch.where(cumulative[i] >= half, values[i], median)
        return median
