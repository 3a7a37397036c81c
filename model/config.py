"""Run configuration: one typed tree, loaded from YAML plus ``key=value`` overrides.

Torch-free, because the model card embeds ``GeneratorConfig`` and the service
must rebuild and check it without torch. Every field has the paper's default
where the paper gives one; ``extra="forbid"`` turns a typo in a config file or
an override into an error instead of a silently ignored setting.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator

from model.codec import DepthEncoding
from model.geometry import Intrinsics


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


#: The generator settings that only say how trained weights are run (``GeneratorConfig.run_as``).
INFERENCE_ONLY = ("flip_average", "median_radius", "median_sigma", "median_spacing", "upsample_sigma")


class GeneratorConfig(_Strict):
    """pix2pixHD global generator. The paper: 32 filters in the first layer."""

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
    skips: bool = Field(
        False,
        description="beyond the paper: add each encoder stage's output to the decoder stage of the same "
        "size (U-Net style, parameter-free), so fine structure need not pass through the 1/2^n bottleneck",
    )
    global_offset: bool = Field(
        False,
        description="beyond the paper: a per-image log-depth offset, pooled from the whole bottleneck and "
        "added before the output's tanh. Instance norm strips each image's feature means at every layer, "
        "so without it a view's absolute distance must be coded in the features' spatial patterns",
    )
    flip_average: bool = Field(
        False,
        description="beyond the paper, inference only: also run the mirrored image and average the two "
        "depths (test-time augmentation); twice the compute, the same weights",
    )
    median_radius: int = Field(
        0,
        ge=0,
        le=3,
        description="beyond the paper, inference only: give each pixel of the network's output (at its "
        "working scale) the colour-weighted median of the depths in its (2r+1)^2-tap window (model.refine), "
        "so a blurred depth step takes the depth of the side whose colour it shares; 0 = off",
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
    upsample_sigma: float = Field(
        0.0,
        ge=0,
        description="beyond the paper, inference only: bring the working-scale output up to the input's size by "
        "joint bilateral upsampling (model.refine.ColourGuidedUpsample), each tap weighed by how alike its "
        "pooled colour is to the output pixel's, with this colour scale in the input's [-1, 1] units; "
        "0 = plain bilinear upsampling",
    )

    @model_validator(mode="after")
    def _one_dilation_per_block(self) -> GeneratorConfig:
        if self.dilations and (len(self.dilations) != self.n_blocks or min(self.dilations) < 1):
            raise ValueError(
                f"dilations needs one value >= 1 per residual block ({self.n_blocks}), got {self.dilations}"
            )
        return self

    def run_as(self, overrides: dict[str, Any]) -> GeneratorConfig:
        """This config with some of its ``INFERENCE_ONLY`` settings changed, validated.

        These change how trained weights are run, never which weights there are, so
        ``evaluate`` and ``export`` may set them on any checkpoint or published version.
        """
        other = set(overrides) - set(INFERENCE_ONLY)
        if other:
            raise ValueError(
                f"{sorted(other)} shape the weights; only {list(INFERENCE_ONLY)} can change after training"
            )
        return GeneratorConfig.model_validate({**self.model_dump(), **overrides})

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

        Lets a torch-free loader check that exported weights match this config;
        ``tests/test_networks_losses.py`` keeps it equal to ``GlobalGenerator``'s.
        """
        ngf = self.ngf
        shapes = [(ngf, self.input_nc, 7, 7)]
        shapes += [(ngf * 2 ** (i + 1), ngf * 2**i, 3, 3) for i in range(self.n_downsample)]
        c = ngf * 2**self.n_downsample
        shapes += [(c, c, 3, 3)] * (2 * self.n_blocks)
        # ConvTranspose2d weights are (in, out, k, k).
        shapes += [
            (ngf * 2 ** (self.n_downsample - i), ngf * 2 ** (self.n_downsample - i - 1), 3, 3)
            for i in range(self.n_downsample)
        ]
        shapes.append((self.output_nc, ngf, 7, 7))
        if self.global_offset:
            c = ngf * 2**self.n_downsample  # the bottleneck's channels
            shapes += [(c // 2, c, 1, 1), (self.output_nc, c // 2, 1, 1)]
        return shapes


class DiscriminatorConfig(_Strict):
    """Multi-scale PatchGAN: D1 at full resolution, D2 at half, and so on."""

    ndf: int = Field(32, ge=1)
    n_layers: int = Field(3, ge=1)
    num_d: int = Field(2, ge=1)


class LossConfig(_Strict):
    """Formula (2) or LSGAN, plus mu times formula (3)'s feature matching."""

    gan_mode: Literal["lsgan", "vanilla"] = Field(
        "lsgan", description="lsgan (pix2pixHD default) or vanilla (formula (2), log-likelihood)"
    )
    feature_matching: float = Field(10.0, ge=0, description="mu in the paper")
    l1_depth: float = Field(0.0, ge=0, description="beyond the paper, opt-in: masked L1 between encoded depths")
    gradient_matching: float = Field(
        0.0,
        ge=0,
        description="beyond the paper, opt-in: masked L1 between the encoded depths' gradients at 4 scales",
    )


class OptimConfig(_Strict):
    """Adam as in the paper; optional pix2pixHD-style linear decay to zero and a weight average.

    The average (``ema``) smooths the step-to-step wander of a GAN generator, which on a
    small validation slice makes checkpoints 200 steps apart score very differently.
    """

    lr: float = Field(0.0002, gt=0)
    beta1: float = 0.5
    beta2: float = 0.999
    decay_start: int | None = Field(None, ge=0, description="step where linear decay begins")
    decay_steps: int = Field(0, ge=0, description="steps over which lr falls to zero")
    ema: float = Field(
        0.0,
        ge=0,
        lt=1,
        description="decay of a moving average of G's weights, which is validated, checkpointed "
        "and exported in place of the raw weights; 0 = off",
    )

    def lr_at(self, step: int) -> float:
        if self.decay_start is None or step < self.decay_start or self.decay_steps == 0:
            return self.lr
        return self.lr * max(0.0, 1.0 - (step - self.decay_start) / self.decay_steps)

    def ema_at(self, step: int) -> float:
        """The average's decay at ``step``, ramped up early so the random start fades quickly."""
        return min(self.ema, (1 + step) / (10 + step))


FORMATS = ("7scenes", "tum", "nyu", "csv")


class ColourCamera(_Strict):
    """The colour camera as seen from the depth camera, in pixels of the same image size."""

    model_config = ConfigDict(frozen=True)

    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float = 0.0
    #: Turn about the optical axis relative to the depth camera, degrees (x towards y). The two
    #: lenses are mounted separately, so a fraction of a degree is usual; at 300 px from the
    #: centre, 0.5 degrees moves an edge by about 2.6 px.
    roll_deg: float = 0.0

    def intrinsics(self, width: int, height: int) -> Intrinsics:
        return Intrinsics(self.fx, self.fy, self.cx, self.cy, width, height)

    def flow(self) -> str:
        """YAML flow, as a data source's ``colour_camera`` and ``evaluate --colour-camera`` take it.

        Offsets at their default (no baseline, no roll) are left out, so a camera fitted
        before the roll existed prints as it did then and its commands stay the same.
        """
        fields = self.model_dump(exclude_defaults=True)
        return "{" + ", ".join(f"{k}: {round(v, 4):g}" for k, v in fields.items()) + "}"

    def resized(self, scale: float) -> ColourCamera:
        """The same camera pair after both images are resized by ``scale`` (pixel-centre convention)."""
        if scale == 1.0:
            return self
        return self.model_copy(
            update={
                "fx": self.fx * scale,
                "fy": self.fy * scale,
                "cx": (self.cx + 0.5) * scale - 0.5,
                "cy": (self.cy + 0.5) * scale - 0.5,
            }
        )


class DataSource(_Strict):
    """One dataset on disk. ``root`` is a folder, or a file for nyu and csv."""

    format: Literal["7scenes", "tum", "nyu", "csv"]
    root: Path
    frames: str | None = Field(None, description="7scenes: inclusive ranges, e.g. '0-799' or '0-9,20-29'")
    split: Literal["train", "test", "all"] = Field("all", description="nyu: the official 795/654 split")
    splits_file: Path | None = Field(None, description="nyu: splits.mat (default: beside the .mat)")
    licence: str | None = Field(None, description="overrides the format's known licence")
    colour_camera: ColourCamera | None = Field(
        None, description="train on depth moved into this colour camera (raw Kinect depth is not registered)"
    )


class TransformConfig(_Strict):
    """Paired random transforms for training; one parameter draw moves RGB, depth and intrinsics."""

    size: tuple[int, int] = Field((240, 320), description="training crop (height, width)")
    scale: tuple[float, float] = Field((0.5, 0.6), description="resize factor range applied before cropping")
    flip: bool = True
    brightness: float = Field(0.2, ge=0)
    contrast: float = Field(0.2, ge=0)
    saturation: float = Field(0.2, ge=0)
    rotate_deg: float = Field(
        0.0,
        ge=0,
        le=30,
        description="largest virtual camera turn about each axis (yaw, pitch, roll), in degrees; 0 = off",
    )
    zoom_depth: bool = Field(
        False,
        description="beyond the paper (Eigen et al. 2014's scale augmentation): a frame enlarged z times beyond "
        "the scale that just fills the crop is shown as if seen from z times closer, its depth divided by z; "
        "off, a zoom keeps depth, as a longer lens would",
    )
    zoom_out: bool = Field(
        False,
        description="a scale below the one that fills the crop shrinks the frame inside black, depth-less "
        "borders instead of being raised to it; with zoom_depth that is a step back, so enlargements and "
        "reductions can balance around no change",
    )


class DataConfig(_Strict):
    train: list[DataSource]
    val: list[DataSource] = []
    val_scale: float = Field(0.5, gt=0, le=1, description="validation images are resized by this")
    transform: TransformConfig = TransformConfig()
    eval_min_m: float = Field(0.1, gt=0, description="metrics use ground truth in [eval_min_m, eval_max_m]")
    eval_max_m: float = Field(10.0, gt=0)


class LoopConfig(_Strict):
    out_dir: Path = Path("runs/default")
    steps: int = Field(1000, ge=1)
    batch_size: int = Field(4, ge=1, description="per process")
    num_workers: int = Field(2, ge=0)
    seed: int = 0
    device: Literal["auto", "cpu", "cuda"] = "auto"
    amp: bool = Field(True, description="mixed precision on CUDA (ignored on CPU)")
    log_every: int = Field(10, ge=1)
    val_every: int = Field(500, ge=1)
    checkpoint_every: int = Field(500, ge=1)
    select_metric: Literal["rel", "rmse", "log10", "delta1"] = "rel"
    threads: int | None = Field(None, ge=1, description="torch CPU threads per process")


class RunConfig(_Strict):
    """Everything that defines a training run; saved in checkpoints and cards."""

    generator: GeneratorConfig = GeneratorConfig()
    discriminator: DiscriminatorConfig = DiscriminatorConfig()
    loss: LossConfig = LossConfig()
    optim: OptimConfig = OptimConfig()
    depth: DepthEncoding = DepthEncoding()
    data: DataConfig
    train: LoopConfig = LoopConfig()

    @model_validator(mode="after")
    def _crop_fits_grid(self) -> RunConfig:
        m = self.generator.core_multiple  # training crops are already at the working scale
        h, w = self.data.transform.size
        if h % m or w % m:
            raise ValueError(f"data.transform.size {h}x{w} must be a multiple of {m} (2^n_downsample)")
        return self


def parse_override(text: str) -> tuple[list[str], Any]:
    """``a.b.c=value`` -> (['a', 'b', 'c'], value parsed as YAML)."""
    key, sep, raw = text.partition("=")
    if not sep or not key:
        raise ValueError(f"override {text!r} is not of the form section.key=value")
    return key.split("."), yaml.safe_load(raw)


def apply_overrides(tree: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Set dotted keys in a nested dict (a copy of it at each level we touch)."""
    out = dict(tree)
    for text in overrides:
        path, value = parse_override(text)
        node = out
        for part in path[:-1]:
            child = node.get(part)
            node[part] = dict(child) if isinstance(child, dict) else {}
            node = node[part]
        node[path[-1]] = value
    return out


def complete_config(saved: dict[str, Any]) -> dict[str, Any]:
    """A saved run config with every key filled in.

    Runs save their whole config, so a key missing from an older run is one added
    since, which that run used at its default: filling it in keeps it out of
    report diffs and lets the run resume.
    """
    return RunConfig.model_validate(saved).model_dump(mode="json")


def load_config(path: Path | None, overrides: list[str] = ()) -> RunConfig:
    """A YAML file plus overrides. Relative data paths resolve against the working directory."""
    tree: dict[str, Any] = {}
    if path is not None:
        tree = yaml.safe_load(Path(path).read_text()) or {}
    tree = apply_overrides(tree, list(overrides))
    return RunConfig.model_validate(tree)
