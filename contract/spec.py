"""What a generator is (its architecture) apart from how trained weights are run (inference settings).

The two change at different times. ``GeneratorSpec`` is fixed when training starts:
the weights only fit the network it describes, and a torch-free loader checks an
exported file against ``weight_shapes``. ``InferenceSettings`` may change on any
trained weights (``rgb2cloud evaluate`` and ``export`` take ``--inference key=value``):
a new setting is a field here plus the code that applies it in the exported graph
(``trainer.inference``), nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from contract.errors import UserError


class Strict(BaseModel):
    """A settings model that refuses unknown keys: a typo is an error, never a silently ignored setting."""

    model_config = ConfigDict(extra="forbid")


#: EfficientNet-Lite0's stages, as Google's ``efficientnet_lite_builder`` gives them (ReLU6, no
#: squeeze-excitation, a 32-channel stem): (repeats, kernel, stride, expansion, output channels).
EFFICIENTNET_LITE0_STAGES: tuple[tuple[int, int, int, int, int], ...] = (
    (1, 3, 1, 1, 16),
    (2, 3, 2, 6, 24),
    (2, 5, 2, 6, 40),
    (3, 3, 2, 6, 80),
    (3, 5, 1, 6, 112),
    (4, 5, 2, 6, 192),
    (1, 3, 1, 6, 320),
)
#: The stages whose last output feeds the decoder: strides 2, 4, 8, 16 and 32.
EFFICIENTNET_SKIP_STAGES = (0, 1, 2, 4, 6)
EFFICIENTNET_STEM = 32


@dataclass(frozen=True)
class EncoderBlock:
    """One inverted-bottleneck block of an EfficientNet-Lite encoder."""

    stage: int
    cin: int
    cout: int
    kernel: int
    stride: int
    expand: int


def encoder_blocks(stages: tuple[tuple[int, int, int, int, int], ...]) -> list[EncoderBlock]:
    """Every block in order: a stage's first block changes channels and stride, its repeats keep them."""
    blocks, cin = [], EFFICIENTNET_STEM
    for index, (repeats, kernel, stride, expand, cout) in enumerate(stages):
        for r in range(repeats):
            blocks.append(EncoderBlock(index, cin, cout, kernel, stride if r == 0 else 1, expand))
            cin = cout
    return blocks


#: What ``GeneratorSpec.encoder`` fixes in the rest of the spec, for an encoder other than pix2pixHD's own.
PRETRAINED_ENCODER_FIXES: dict[str, Any] = {"n_downsample": 5, "n_blocks": 0, "dilations": [], "upsampler": "bilinear"}


class GeneratorSpec(Strict):
    """pix2pixHD's global generator, or a U-Net on a pretrained encoder. The paper: 32 filters in the first layer."""

    encoder: Literal["pix2pixhd", "efficientnet-lite0"] = Field(
        "pix2pixhd",
        description="pix2pixhd: the paper's generator, trained from random weights; efficientnet-lite0: beyond the "
        "paper, a U-Net whose encoder is EfficientNet-Lite0 (started from ImageNet weights when training), with "
        "skips at strides 2-32 and a decoder of `ngf` channels per stage, BatchNorm (folded at export) and "
        "`bilinear` upsampling; it fixes n_downsample 5, n_blocks 0 and the upsampler, and `dropout` acts on "
        "the encoder's deepest features",
    )
    input_nc: int = 3
    output_nc: int = 1
    ngf: int = Field(32, ge=1, description="filters in the first layer")
    n_downsample: int = Field(4, ge=0, le=6)
    n_blocks: int = Field(9, ge=0)
    dropout: float = Field(
        0.0,
        ge=0.0,
        lt=1.0,
        description="the paper's noise input Z, as pix2pix: dropout in the residual blocks, training only",
    )
    work_scale: int = Field(
        1,
        ge=1,
        le=8,
        description="beyond the paper: the network runs at 1/work_scale of the input's resolution "
        "(average pool in, bilinear upsample out); training feeds images already at that scale",
    )
    dilations: list[int] = Field(
        default_factory=list,
        description="beyond the paper: the dilation of each residual block's first convolution "
        "(one per block; empty = all 1, the paper). Widens what one output pixel sees, for the "
        "room-scale cues that fix a view's absolute depth, with the same weights and compute",
    )

    upsampler: Literal["transpose", "bilinear", "shuffle", "resize"] = Field(
        "transpose",
        description="how each decoder stage doubles the resolution. transpose: pix2pixHD's 3x3 transposed "
        "convolution, whose uneven overlap leaves a periodic ripple (periods 2, 4, 8 px) in depth; bilinear: a "
        "3x3 convolution, then a bilinear 2x resize, which has no ripple by construction and the same "
        "multiply-adds; shuffle: a 3x3 convolution to 4x the channels and a pixel shuffle, ICNR-initialised; "
        "resize: a nearest 2x resize, then a 3x3 convolution (the last two are ripple-free too, at 4x the stage's "
        "multiply-adds: bench/generator_size.py)",
    )

    @model_validator(mode="before")
    @classmethod
    def _encoder_fixes_the_rest(cls, data: Any) -> Any:
        """A pretrained encoder decides depth, blocks and upsampler: filled in where left out, checked where given."""
        if not isinstance(data, dict) or data.get("encoder", "pix2pixhd") == "pix2pixhd":
            return data
        for key, fixed in PRETRAINED_ENCODER_FIXES.items():
            if key in data and data[key] != fixed:
                raise ValueError(f"encoder {data['encoder']} needs {key} {fixed!r}, got {data[key]!r}")
        return {**PRETRAINED_ENCODER_FIXES, **data}

    @model_validator(mode="after")
    def _one_dilation_per_block(self) -> GeneratorSpec:
        if self.dilations and (len(self.dilations) != self.n_blocks or min(self.dilations) < 1):
            raise ValueError(
                f"dilations needs one value >= 1 per residual block ({self.n_blocks}), got {self.dilations}"
            )
        return self

    @property
    def core_multiple(self) -> int:
        """Height and width the network itself needs, at its working scale."""
        return 2**self.n_downsample

    @property
    def input_multiple(self) -> int:
        """Input height and width must be multiples of this."""
        return self.core_multiple * self.work_scale

    def weight_shapes(self) -> list[tuple[int, ...]]:
        """Every convolution's weight shape, in network order, without building the network.

        Lets a torch-free loader check that exported weights match this spec;
        a trainer test keeps it equal to ``trainer.networks.build_generator``'s.
        """
        if self.encoder != "pix2pixhd":
            return self._unet_weight_shapes()
        ngf = self.ngf
        shapes = [(ngf, self.input_nc, 7, 7)]
        shapes += [(ngf * 2 ** (i + 1), ngf * 2**i, 3, 3) for i in range(self.n_downsample)]
        c = ngf * 2**self.n_downsample
        shapes += [(c, c, 3, 3)] * (2 * self.n_blocks)
        for i in range(self.n_downsample):
            c = ngf * 2 ** (self.n_downsample - i)
            shapes.append(
                (c, c // 2, 3, 3)  # ConvTranspose2d weights are (in, out, k, k)
                if self.upsampler == "transpose"
                else (2 * c if self.upsampler == "shuffle" else c // 2, c, 3, 3)  # shuffle: 4 x c/2 outputs
            )
        shapes.append((self.output_nc, ngf, 7, 7))
        return shapes

    def _unet_weight_shapes(self) -> list[tuple[int, ...]]:
        """The encoder's convolutions (no ImageNet head), then the decoder's, from the deepest stage up."""
        shapes: list[tuple[int, ...]] = [(EFFICIENTNET_STEM, self.input_nc, 3, 3)]
        blocks = encoder_blocks(EFFICIENTNET_LITE0_STAGES)
        for b in blocks:
            hidden = b.cin * b.expand
            if b.expand != 1:
                shapes.append((hidden, b.cin, 1, 1))
            shapes += [(hidden, 1, b.kernel, b.kernel), (b.cout, hidden, 1, 1)]
        skips = [EFFICIENTNET_LITE0_STAGES[s][4] for s in EFFICIENTNET_SKIP_STAGES]
        c, below = self.ngf, skips[-1]
        for skip in reversed(skips[:-1]):
            shapes += [(c, below, 3, 3), (c, c + skip, 3, 3)]
            below = c
        shapes += [(c, c, 3, 3), (self.output_nc, c, 3, 3)]
        return shapes


class InferenceSettings(Strict):
    """How trained weights are run: refinements baked into the exported graph, never trained."""

    median_radius: int = Field(
        0,
        ge=0,
        le=3,
        description="beyond the paper: give each pixel of the network's output (at its working scale) the "
        "colour-weighted median of the depths in its (2r+1)^2-tap window, so a blurred depth step takes the "
        "depth of the side whose colour it shares; 0 = off",
    )
    median_sigma: float = Field(
        0.1,
        gt=0,
        description="the colour-weighted median's colour scale, in the input's [-1, 1] units: a neighbour "
        "whose RGB differs by sigma weighs exp(-1/2) of one with the pixel's own colour",
    )
    median_spacing: int = Field(
        1,
        ge=1,
        le=4,
        description="pixels (at the working scale) between the colour-weighted median's taps: 2 reaches twice "
        "as far at the same cost",
    )

    def updated(self, changes: dict[str, Any]) -> InferenceSettings:
        """These settings with ``changes`` applied and validated (an unknown key is an error)."""
        return InferenceSettings.model_validate({**self.model_dump(), **changes})

    def describe(self) -> str:
        """The settings that change the output, in words, for labels and reports ('' when none)."""
        if not self.median_radius:
            return ""
        taps = 2 * self.median_radius + 1
        return f"colour-weighted median {taps}x{taps} taps {self.median_spacing} px apart, sigma {self.median_sigma:g}"


def parse_inference_options(options: list[str]) -> dict[str, Any]:
    """``["median_radius=2", ...]`` -> ``{"median_radius": 2, ...}``, checked against ``InferenceSettings``."""
    changes: dict[str, Any] = {}
    for option in options:
        key, sep, value = option.partition("=")
        if not sep or key not in InferenceSettings.model_fields:
            raise UserError(
                f"--inference {option!r}: expected KEY=VALUE with KEY one of {list(InferenceSettings.model_fields)}"
            )
        changes[key] = value
    validated = InferenceSettings().updated(changes)
    return {key: getattr(validated, key) for key in changes}
