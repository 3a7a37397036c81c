"""Inference-only refinement of a predicted depth map by the photo it came from.

The generator blurs a depth step over a few pixels, and in the blur every pixel
is neither the near nor the far surface's depth, so it fails delta1 whichever
side it belongs to (recipe steps 18-21: on the most test-like validation views a
third of the pixels beside a step fail, against under 1% of the rest). The photo
is sharp there. A colour-weighted median (Ma et al., "Constant time weighted
median filtering for stereo matching and beyond", ICCV 2013) gives each pixel the
median of the depths around it, each counted by how alike its colour is to the
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

import math

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


class ColourGuidedUpsample(nn.Module):
    """The working-scale depth brought up to the photo's size, each output pixel guided by its own colour.

    The generator runs at 1/``scale`` of the photo, so a depth step the median has made
    sharp there still becomes a ramp ``scale`` pixels wide when it is upsampled
    bilinearly, and the ramp's pixels are neither surface's depth. Joint bilateral
    upsampling (Kopf et al., "Joint bilateral upsampling", SIGGRAPH 2007) weighs each
    working-scale tap by a tent over its distance, as bilinear interpolation does, times
    how alike its colour (the pooled photo the network saw) is to the output pixel's own
    colour (the full-size photo): a pixel on an edge the small grid cannot place takes
    the depth of the side it looks like. The taps are bilinear interpolation's own two
    by two, so with a very large ``sigma`` the result is ``F.interpolate(...,
    mode="bilinear")`` exactly, and ``sigma`` 0 is that plain upsampling. (No wider tent
    is offered: recipe step 24 found these 2x2 taps change delta1 by under 0.001, so
    the ramp is not where it fails.)

    Each of the scale^2 sub-pixel positions has fixed tap offsets and tent weights, so
    it is computed on the small grid by slicing and the positions are interleaved by a
    pixel shuffle: plain element-wise work that TorchScript and ONNX export in-graph.
    """

    taps: list[list[tuple[int, int, float]]]  # per sub-pixel position: (row offset, column offset, tent weight)

    def __init__(self, scale: int, sigma: float):
        super().__init__()
        self.scale_factor = scale
        self.sigma = sigma
        self.colour_scale = -0.5 / (sigma * sigma) if sigma > 0 else 0.0
        tents = [_bilinear_taps((phase + 0.5) / scale - 0.5) for phase in range(scale)]
        self.taps = [[(dy, dx, wy * wx) for dy, wy in rows for dx, wx in cols] for rows in tents for cols in tents]

    def forward(self, depth: torch.Tensor, rgb_small: torch.Tensor, rgb: torch.Tensor) -> torch.Tensor:
        k = self.scale_factor
        if self.sigma <= 0:
            return F.interpolate(depth, scale_factor=float(k), mode="bilinear", align_corners=False)
        height, width = depth.shape[2], depth.shape[3]
        p = 1
        depth_pad = F.pad(depth, [p, p, p, p], mode="replicate")
        rgb_pad = F.pad(rgb_small, [p, p, p, p], mode="replicate")
        positions: list[torch.Tensor] = []
        for index, taps in enumerate(self.taps):
            colour = rgb[:, :, index // k :: k, index % k :: k]  # this sub-pixel position's full-size pixels
            distances: list[torch.Tensor] = []
            for dy, dx, _ in taps:
                difference = rgb_pad[:, :, p + dy : p + dy + height, p + dx : p + dx + width] - colour
                distances.append((difference * difference).sum(1, keepdim=True))
            # Measured from the closest colour, so the best tap weighs its tent and the sum never underflows;
            # the common factor this removes cancels in the normalisation.
            closest = distances[0]
            for distance in distances[1:]:
                closest = torch.minimum(closest, distance)
            total = torch.zeros_like(depth)
            weight_sum = torch.zeros_like(depth)
            for i, (dy, dx, tent) in enumerate(taps):
                weight = tent * torch.exp(self.colour_scale * (distances[i] - closest))
                total = total + weight * depth_pad[:, :, p + dy : p + dy + height, p + dx : p + dx + width]
                weight_sum = weight_sum + weight
            positions.append(total / weight_sum)
        return F.pixel_shuffle(torch.cat(positions, 1), k)


def _bilinear_taps(offset: float) -> list[tuple[int, float]]:
    """The working-scale taps of a sample ``offset`` (-0.5 to 0.5) pixels from its grid point, with weights > 0."""
    first = math.floor(offset)
    taps = [(first, 1.0 - (offset - first)), (first + 1, offset - first)]
    return [(o, w) for o, w in taps if w > 0]
