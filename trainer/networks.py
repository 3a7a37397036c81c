"""The paper's networks, after pix2pixHD: a global generator and a multi-scale PatchGAN; and beyond the
paper, a U-Net generator on a pretrained encoder.

Each network is one small class that reads top to bottom like the paper's
description. Instance norm without affine parameters, as pix2pixHD uses.
"""

import torch
import torch.nn.functional as F
from torch import nn

from contract.spec import EFFICIENTNET_LITE0_STAGES, EFFICIENTNET_SKIP_STAGES, GeneratorSpec
from trainer.config import DiscriminatorConfig
from trainer.efficientnet import EfficientNetLite


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


def upsampler(kind: str, channels: int) -> nn.Module:
    """One decoder stage's 2x upsampling from ``channels`` to ``channels // 2`` (``GeneratorSpec.upsampler``).

    Each kind is one module, so the layers after it keep their state-dict keys whichever is chosen.
    """
    out = channels // 2
    if kind == "transpose":
        return nn.ConvTranspose2d(channels, out, 3, stride=2, padding=1, output_padding=1)
    if kind == "bilinear":
        return nn.Sequential(
            nn.Conv2d(channels, out, 3, padding=1), nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False)
        )
    if kind == "shuffle":
        return nn.Sequential(nn.Conv2d(channels, out * 4, 3, padding=1), nn.PixelShuffle(2))
    return nn.Sequential(nn.Upsample(scale_factor=2, mode="nearest"), nn.Conv2d(channels, out, 3, padding=1))


class GlobalGenerator(nn.Module):
    """pix2pixHD's global generator: 7x7 front-end, n_downsample stride-2 convs, n_blocks
    residual blocks (optionally dilated), n_downsample 2x upsamplers, 7x7 output conv, tanh.

    It runs at its working scale: height and width must be multiples of
    ``spec.core_multiple``. The trainer feeds it frames already at that scale, so the
    losses and the discriminators work where the network does; ``trainer.inference``
    wraps it for full-size photos (pooling, refinement, upsampling) and is what export writes.
    """

    def __init__(self, spec: GeneratorSpec):
        super().__init__()
        self.spec = spec
        ngf = spec.ngf
        layers: list[nn.Module] = [nn.ReflectionPad2d(3), nn.Conv2d(spec.input_nc, ngf, 7), _norm(ngf), nn.ReLU(True)]
        for i in range(spec.n_downsample):
            c = ngf * 2**i
            layers += [nn.Conv2d(c, c * 2, 3, stride=2, padding=1), _norm(c * 2), nn.ReLU(True)]
        c = ngf * 2**spec.n_downsample
        layers += [ResnetBlock(c, spec.dropout, d) for d in spec.dilations or [1] * spec.n_blocks]
        for i in range(spec.n_downsample):
            c = ngf * 2 ** (spec.n_downsample - i)
            layers += [upsampler(spec.upsampler, c), _norm(c // 2), nn.ReLU(True)]
        layers += [nn.ReflectionPad2d(3), nn.Conv2d(ngf, spec.output_nc, 7), nn.Tanh()]
        self.model = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


def conv_bn_relu(cin: int, cout: int) -> nn.Sequential:
    """A 3x3 convolution, BatchNorm (folded into the convolution at export) and ReLU.

    Replicate padding: no zeros at the border for the decoder to learn an edge from, and unlike
    reflection it works on the 1-pixel maps at stride 32 of the smallest photos.
    """
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1, padding_mode="replicate", bias=False), nn.BatchNorm2d(cout), nn.ReLU(True)
    )


class DecoderStage(nn.Module):
    """One U-Net decoder stage: a convolution, a bilinear 2x resize (``upsampler: bilinear``, no ripple),
    the encoder's features at that stride concatenated, and a convolution that merges them."""

    def __init__(self, cin: int, skip: int, channels: int):
        super().__init__()
        self.reduce = conv_bn_relu(cin, channels)
        self.merge = conv_bn_relu(channels + skip, channels)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = F.interpolate(self.reduce(x), scale_factor=2.0, mode="bilinear", align_corners=False)
        return self.merge(torch.cat([x, skip], 1))


class UNetGenerator(nn.Module):
    """``encoder: efficientnet-lite0``: EfficientNet-Lite0 features at strides 2-32, a decoder of ``ngf``
    channels per stage back to stride 1, and a 3x3 output convolution with tanh (log-depth, as the codec reads).

    Runs at its working scale like ``GlobalGenerator``: height and width multiples of 32. The spec's
    ``dropout`` (the paper's noise Z) drops the deepest features during training.
    """

    def __init__(self, spec: GeneratorSpec):
        super().__init__()
        self.spec = spec
        self.encoder = EfficientNetLite(EFFICIENTNET_LITE0_STAGES)
        self.frozen_encoder = False
        skips = [EFFICIENTNET_LITE0_STAGES[s][4] for s in EFFICIENTNET_SKIP_STAGES]
        c = spec.ngf
        self.dropout = nn.Dropout(spec.dropout) if spec.dropout > 0 else nn.Identity()
        below = [skips[-1]] + [c] * 3  # each stage's input: the deepest features, then the stage before
        self.stages = nn.ModuleList(
            DecoderStage(cin, skip, c) for cin, skip in zip(below, reversed(skips[:-1]), strict=True)
        )
        self.last = conv_bn_relu(c, c)
        self.out = nn.Conv2d(c, spec.output_nc, 3, padding=1, padding_mode="replicate")

    def freeze_encoder(self) -> None:
        """Keep the encoder as loaded: no gradients, and its BatchNorm statistics never updated."""
        self.frozen_encoder = True
        self.encoder.requires_grad_(False)
        self.encoder.eval()

    def train(self, mode: bool = True) -> "UNetGenerator":
        super().train(mode)
        if self.frozen_encoder:
            self.encoder.eval()
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        features = self.encoder(x)
        x = self.dropout(features[-1])
        for i, stage in enumerate(self.stages):
            x = stage(x, features[len(features) - 2 - i])
        x = F.interpolate(self.last(x), scale_factor=2.0, mode="bilinear", align_corners=False)
        return torch.tanh(self.out(x))


def build_generator(spec: GeneratorSpec) -> nn.Module:
    """The generator a spec describes, freshly initialised by PyTorch (``trainer.gan`` sets its starting weights)."""
    return GlobalGenerator(spec) if spec.encoder == "pix2pixhd" else UNetGenerator(spec)


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
