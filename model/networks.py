"""The paper's networks, after pix2pixHD: a global generator and a multi-scale PatchGAN.

Each network is one small class that reads top to bottom like the paper's
description. Instance norm without affine parameters, as pix2pixHD uses.
"""

import torch
import torch.nn.functional as F
from torch import nn

from model.config import DiscriminatorConfig, GeneratorConfig
from model.refine import ColourGuidedUpsample, ColourWeightedMedian


def _norm(channels: int) -> nn.Module:
    return nn.InstanceNorm2d(channels, affine=False)


class ResnetBlock(nn.Module):
    """Two reflection-padded 3x3 convolutions with a skip; optional dropout between them.

    The dropout is the paper's noise input Z (G: {X, Z} -> Y), realised as pix2pix
    does; it is active in ``train()`` mode only, so inference is deterministic.
    A ``dilation`` above 1 spreads the first convolution's taps; it is zero-padded,
    because reflection padding needs the map to be wider than the dilation and
    the service takes images small enough for a 1/16-scale map to be a few pixels.
    """

    def __init__(self, channels: int, dropout: float, dilation: int = 1):
        super().__init__()
        first: list[nn.Module] = (
            [nn.ReflectionPad2d(1), nn.Conv2d(channels, channels, 3)]
            if dilation == 1
            else [nn.Conv2d(channels, channels, 3, padding=dilation, dilation=dilation)]
        )
        layers: list[nn.Module] = [
            *first,
            _norm(channels),
            nn.ReLU(True),
        ]
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        layers += [nn.ReflectionPad2d(1), nn.Conv2d(channels, channels, 3), _norm(channels)]
        self.block = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.block(x)


class GlobalOffset(nn.Module):
    """One log-depth offset per image, from the whole bottleneck map.

    A 1x1 convolution and ReLU score every bottleneck cell, their mean over the map
    describes the view, and a second 1x1 convolution turns that into an offset per
    output channel. Instance norm removes each image's per-channel means at every
    layer of the generator, so a plain generator can set a view's absolute distance
    only through the spatial shape of its features; this path sets it directly.
    The last convolution starts at zero, so training starts from the plain network.
    Recipe step 14 measured it on 7-Scenes: no better on the validation folds, and
    new views were still seen too far, so the bundled model does not use it.
    """

    def __init__(self, channels: int, output_nc: int):
        super().__init__()
        self.embed = nn.Conv2d(channels, channels // 2, 1)
        self.out = nn.Conv2d(channels // 2, output_nc, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(F.relu(self.embed(x)).mean((2, 3), keepdim=True))


class GlobalGenerator(nn.Module):
    """7x7 front-end, n_downsample stride-2 convs, n_blocks residual blocks
    (optionally dilated), n_downsample transposed convs, 7x7 output conv, tanh.

    Height and width must be multiples of ``config.input_multiple``; callers pad
    (``model.geometry.pad_to_multiple``) and crop back.

    With ``work_scale`` k > 1 the network sees a k-times average-pooled image and
    its output is bilinearly upsampled back: a 640x480 photo costs what a
    320x240 one does, and the net sees the whole frame instead of a crop. The
    trainer feeds frames already at the working scale (``at_working_scale``), so
    the losses and the discriminators work where the network does.

    With ``skips`` each encoder stage's output (front-end, then every downsampling
    but the last) is added to the decoder's output of the same size, U-Net style.
    The sums need no weights, so the layers and their state-dict keys are the ones
    a plain generator has; only the wiring differs. Without them every edge and
    thin object must be rebuilt from the 1/2^n bottleneck by transposed convs.

    With ``global_offset`` a ``GlobalOffset`` reads the bottleneck after the residual
    blocks and its per-image offset is added to the output just before the tanh.

    With ``flip_average`` the full-size path also predicts the left-right mirror
    and averages it back in (test-time augmentation): the same weights, a second
    pass. Whether it helps depends on the data, so measure it on validation frames
    (on 7-Scenes it did not; see the README).

    With ``median_radius`` the network's output goes through
    ``model.refine.ColourWeightedMedian``, guided by the photo at the same scale,
    before it is upsampled: that is the grid the network blurs on, and at
    work_scale 2 it is a quarter of the pixels, which is what keeps the filter's
    cost (a sorting network per pixel) well inside the 300 ms budget.

    With ``upsample_sigma`` that output is brought up to the input's size by
    ``model.refine.ColourGuidedUpsample`` instead of plain bilinear interpolation:
    the taps bilinear interpolation uses, weighed by how alike their colour is to
    each full-size pixel's, so a step lands on the photo's edge, not across a
    ``work_scale``-pixel ramp.

    Training never takes these paths; they live in the graph so that every
    exported file carries them.
    """

    save_after: list[int]  # class-level, so TorchScript types them even when empty
    add_after: list[int]

    def __init__(self, config: GeneratorConfig):
        super().__init__()
        self.config = config
        self.work_scale = config.work_scale  # plain values, so TorchScript can read them
        self.flip_average = config.flip_average
        self.median = ColourWeightedMedian(config.median_radius, config.median_sigma, config.median_spacing)
        self.upsample = ColourGuidedUpsample(config.work_scale, config.upsample_sigma)
        ngf = config.ngf
        layers: list[nn.Module] = [
            nn.ReflectionPad2d(3),
            nn.Conv2d(config.input_nc, ngf, 7),
            _norm(ngf),
            nn.ReLU(True),
        ]
        # Where each skip leaves (an encoder output at full, 1/2, ... size) and, LIFO, comes back in.
        encoder_outputs: list[int] = []
        decoder_outputs: list[int] = []
        for i in range(config.n_downsample):
            encoder_outputs.append(len(layers) - 1)
            c = ngf * 2**i
            layers += [nn.Conv2d(c, c * 2, 3, stride=2, padding=1), _norm(c * 2), nn.ReLU(True)]
        c = ngf * 2**config.n_downsample
        dilations = config.dilations or [1] * config.n_blocks
        layers += [ResnetBlock(c, config.dropout, d) for d in dilations]
        bottleneck, bottleneck_channels = len(layers) - 1, c
        for i in range(config.n_downsample):
            c = ngf * 2 ** (config.n_downsample - i)
            layers += [
                nn.ConvTranspose2d(c, c // 2, 3, stride=2, padding=1, output_padding=1),
                _norm(c // 2),
                nn.ReLU(True),
            ]
            decoder_outputs.append(len(layers) - 1)
        layers += [nn.ReflectionPad2d(3), nn.Conv2d(ngf, config.output_nc, 7), nn.Tanh()]
        self.model = nn.Sequential(*layers)
        self.save_after = encoder_outputs if config.skips else []
        self.add_after = decoder_outputs if config.skips else []
        # Registered after ``model``, so a plain generator's state-dict keys are unchanged.
        heads = [GlobalOffset(bottleneck_channels, config.output_nc)] if config.global_offset else []
        self.global_offset = nn.ModuleList(heads)
        self.offset_from = bottleneck if config.global_offset else -1
        self.offset_into = len(layers) - 1  # the tanh

    def forward(self, x: torch.Tensor, at_working_scale: bool = False) -> torch.Tensor:
        if at_working_scale:
            return self._core(x)
        if self.flip_average:
            mirrored = torch.flip(self._full_size(torch.flip(x, [3])), [3])
            return 0.5 * (self._full_size(x) + mirrored)
        return self._full_size(x)

    def _full_size(self, x: torch.Tensor) -> torch.Tensor:
        k = self.work_scale
        if k == 1:
            return self.median(self._core(x), x)
        small = F.avg_pool2d(x, k)
        return self.upsample(self.median(self._core(small), small), small, x)

    def _core(self, x: torch.Tensor) -> torch.Tensor:
        """The network at its working scale, with the skips and the global offset when configured."""
        if not self.save_after and self.offset_from < 0:
            return self.model(x)
        saved: list[torch.Tensor] = []
        offset = torch.zeros_like(x[:, :1, :1, :1])
        for i, layer in enumerate(self.model):
            if i == self.offset_into and self.offset_from >= 0:
                x = x + offset
            x = layer(x)
            if i == self.offset_from:
                for head in self.global_offset:
                    offset = head(x)
            if i in self.save_after:
                saved.append(x)
            elif i in self.add_after:
                x = x + saved.pop()
        return x


class GeneratorEnsemble(nn.Module):
    """Several generators of one config run as one: the mean of their tanh outputs.

    It lets ``rgb2cloud evaluate`` score runs that differ only in their seed as one
    model, to measure how much of a run's error averaging cancels (recipe step 13: on
    7-Scenes, little). The tanh output encodes log depth, so this is the geometric mean
    of the members' depths. Its ``forward(x)`` is ``GlobalGenerator``'s inference call,
    so ``TorchModuleGenerator`` runs either.
    """

    def __init__(self, members: list[GlobalGenerator]):
        super().__init__()
        if len(members) < 2:
            raise ValueError("an ensemble needs at least two generators")
        if any(m.config != members[0].config for m in members[1:]):
            raise ValueError("an ensemble's generators must share one config")
        self.config = members[0].config
        self.members = nn.ModuleList(members)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        outputs: list[torch.Tensor] = []
        for member in self.members:
            outputs.append(member(x))
        return torch.stack(outputs).mean(0)


class NLayerDiscriminator(nn.Module):
    """PatchGAN with 4x4 kernels and LeakyReLU 0.2; returns every layer's output.

    The last entry is the patch map of real/fake logits; the ones before it are
    the intermediate features that feature matching compares.
    """

    def __init__(self, input_nc: int, ndf: int, n_layers: int):
        super().__init__()
        kw, pad = 4, 2
        stages: list[list[nn.Module]] = [[nn.Conv2d(input_nc, ndf, kw, 2, pad), nn.LeakyReLU(0.2, True)]]
        nf = ndf
        for _ in range(1, n_layers):
            prev, nf = nf, min(nf * 2, 512)
            stages.append([nn.Conv2d(prev, nf, kw, 2, pad), _norm(nf), nn.LeakyReLU(0.2, True)])
        prev, nf = nf, min(nf * 2, 512)
        stages.append([nn.Conv2d(prev, nf, kw, 1, pad), _norm(nf), nn.LeakyReLU(0.2, True)])
        stages.append([nn.Conv2d(nf, 1, kw, 1, pad)])
        self.stages = nn.ModuleList(nn.Sequential(*s) for s in stages)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        outputs = []
        for stage in self.stages:
            x = stage(x)
            outputs.append(x)
        return outputs


class MultiscaleDiscriminator(nn.Module):
    """``num_d`` PatchGANs; D1 sees full resolution, each next one half the previous.

    Downsampling is a 3x3 average pool, stride 2, padding 1, that does not count
    padded zeros. Input: RGB concatenated with depth along channels.
    """

    def __init__(self, config: DiscriminatorConfig, input_nc: int):
        super().__init__()
        self.config = config
        self.scales = nn.ModuleList(
            NLayerDiscriminator(input_nc, config.ndf, config.n_layers) for _ in range(config.num_d)
        )
        self.downsample = nn.AvgPool2d(3, stride=2, padding=1, count_include_pad=False)

    def forward(self, x: torch.Tensor) -> list[list[torch.Tensor]]:
        results = []
        for i, d in enumerate(self.scales):
            if i:
                x = self.downsample(x)
            results.append(d(x))
        return results
