"""Model cards and the versioned registry. Torch-free: the service loads with this.

A registry is a folder ``<registry>/<name>/<version>/`` holding the exported
generator files and ``card.json``. The card says everything needed to use and
trust the weights: a sha256 per file, the generator spec (to check the weights
against) and the inference settings baked into the exported graph, the input and
depth encodings, the training camera, the data and its licences, and the metrics
with their split.

Cards carry a ``schema_version``. Older cards are migrated on read (``migrate_card``),
never rewritten on disk: their files stay byte for byte what was published.

Versions are immutable: publishing stages into a hidden folder beside the
target and renames it into place, refusing if the version already exists.
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import os
import re
import shutil
import tempfile
from collections.abc import Iterable
from datetime import datetime
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator

from contract.codec import DepthEncoding
from contract.errors import UserError
from contract.geometry import ColourCamera, Intrinsics
from contract.spec import GeneratorSpec, InferenceSettings

CARD_FILE = "card.json"
ONNX_FILE = "generator.onnx"
TORCHSCRIPT_FILE = "generator.torchscript.pt"
#: The generator's weights alone (safetensors: tensors and names, no code), which training starts from.
WEIGHTS_FILE = "generator.safetensors"
INT8_ONNX_FILE = "generator.int8.onnx"
#: The photo every engine and precision is checked against ONNX Runtime fp32 on, wherever a version loads.
SAMPLE_FILE = "sample.png"
SEMVER = re.compile(r"^(0|[1-9]\d*)\.(0|[1-9]\d*)\.(0|[1-9]\d*)(?:-([0-9A-Za-z.-]+))?$")
NAME = re.compile(r"^[a-z0-9][a-z0-9._-]{0,63}$")
SCHEMA_VERSION = 5
#: The paper's six metrics, in its Table 2's order.
PAPER_METRICS = ("rel", "rmse", "log10", "delta1", "delta2", "delta3")
#: What every evaluation reports and a card records: the paper's metrics and the mean point-cloud RMSE.
METRIC_KEYS = (*PAPER_METRICS, "pc_rmse_mean")
#: Generator options that were measured, rejected and removed, with the value that meant "off".
#: A schema-1 card may name them at that value; one that turned an option on describes a graph
#: this code cannot check or reproduce, so it is refused.
RETIRED_GENERATOR_OPTIONS: dict[str, Any] = {
    "skips": False,
    "global_offset": False,
    "flip_average": False,
    "upsample_sigma": 0.0,
}


class CardError(UserError):
    """A card or its files cannot be trusted; the message names the file and the reason."""


class DataRef(BaseModel):
    """One dataset a model saw, with the frames used and the licence that binds them."""

    name: str
    format: str
    frames: str
    licence: str = Field(min_length=1)
    via: str | None = Field(
        None,
        description="the published model (NAME VERSION) this data reached the weights through, when it was "
        "not trained on here: a fitted model inherits its start's data and licences",
    )


class Metrics(BaseModel):
    """The paper's metrics on a named split, plus the mean point-cloud RMSE."""

    split: str = Field(min_length=1, description="dataset and frames, e.g. 7scenes-redkitchen 850-999")
    label: str | None = Field(
        None,
        description="what was scored, when not this model: the model a fit started from, or an image-free "
        "baseline, scored on the same frames for comparison",
    )
    images: int = Field(gt=0)
    depth_range_m: tuple[float, float]
    rel: float
    rmse: float
    log10: float
    delta1: float
    delta2: float
    delta3: float
    pc_rmse_mean: float
    colour_camera: ColourCamera | None = Field(
        None,
        description="set when the prediction was read at this colour camera for each ground-truth depth-camera "
        "pixel (evaluate --colour-camera, a model trained on registered depth); absent: pixel to pixel",
    )

    @classmethod
    def from_result(
        cls,
        result: dict[str, Any],
        split: str,
        depth_range_m: tuple[float, float],
        colour_camera: ColourCamera | None = None,
        label: str | None = None,
    ) -> Metrics:
        """An evaluation's table row (the trainer's ``evaluate_frames`` result) as a card entry."""
        scores = {key: result[key] for key in METRIC_KEYS}
        return cls(
            split=split,
            label=label,
            images=result["images"],
            depth_range_m=depth_range_m,
            colour_camera=colour_camera,
            **scores,
        )


#: A fit's start when it begins from no trained generator: ImageNet's encoder under a fresh decoder (fit's default).
IMAGENET_START = "imagenet"


class FitRecord(BaseModel):
    """How ``rgb2cloud fit`` made a model of one place."""

    fit_id: str | None = Field(
        None, description="the fit's own id (its fit.json's): which run published this version, wherever it ran"
    )
    data: str = Field(description="the recording's path as given")
    start_from: str = Field(
        description="the published version whose generator it started from, or 'imagenet' (a fresh decoder on "
        "ImageNet's encoder; 'scratch' in cards before it was fit's default)"
    )
    start_model: str | None = Field(None, description="that version's NAME VERSION, from its card")
    budget_min: float
    split: dict[str, Any] = Field(description="train, selection, gap and held-out parts: frames, first, last")
    registered_with: ColourCamera | None = Field(
        None, description="the colour camera its depth was registered to, when the recording's was not"
    )


class Int8Graph(BaseModel):
    """The int8 ONNX graph published beside the fp32 one: how it was calibrated, and how close it stays."""

    file: str = INT8_ONNX_FILE
    method: str = Field(description="ONNX Runtime static QDQ quantisation: per-channel int8 weights, uint8 activations")
    calibration: str = Field(description="the activation-range calibration: minmax, entropy or percentile")
    frames: int = Field(description="how many of the model's training frames calibrated it")
    frames_from: list[str] = Field(description="the training data they were spread over")
    fp32_nodes: list[str] = Field(description="nodes left in fp32 (the precision-sensitive ends)")
    parity: dict[str, float] = Field(description="int8 against fp32 depth on the parity image; see trainer.quantize")


class Training(BaseModel):
    data: list[DataRef] = Field(min_length=1)
    steps: int
    duration_s: float
    hardware: str
    config: dict
    fit: FitRecord | None = None


class ModelCard(BaseModel):
    model_config = ConfigDict(extra="forbid")

    schema_version: int = SCHEMA_VERSION
    name: str
    version: str
    created: datetime
    files: dict[str, str] = Field(description="file name -> sha256 hex digest")
    generator: GeneratorSpec
    inference: InferenceSettings = Field(description="the settings baked into the exported graph")
    input_multiple: int
    input_encoding: str = Field(
        description="how the exported graph wants its input; the service serves only the encoding it feeds"
    )
    depth_encoding: DepthEncoding = Field(description="the graph's tanh output -> metres")
    camera: Intrinsics = Field(
        description="the camera at which the generator was trained (its input's scale): the service resamples "
        "every photo to this focal length"
    )
    training: Training
    metrics: list[Metrics] = Field(min_length=1)
    trainer_commit: str
    parity: dict[str, float] = Field(default_factory=dict, description="export vs eager max abs diff")
    int8: Int8Graph | None = Field(
        None, description="an int8 graph beside the fp32 one (``export --precision int8``); none: fp32 only"
    )
    sample: str | None = Field(
        None,
        description="the parity photo at the camera's size, among the card's files: wherever the version loads, "
        "each engine and precision is compared with ONNX Runtime fp32 on it before it is served (a CPU whose "
        "arithmetic differs is caught there); none in versions published before every export shipped one",
    )
    derived_from: str | None = Field(
        None,
        description="the published version whose weights these are, exported again with other inference "
        "settings; its training is this card's training",
    )

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not NAME.match(v):
            raise ValueError(f"name {v!r} must match {NAME.pattern}")
        return v

    @field_validator("version")
    @classmethod
    def _version(cls, v: str) -> str:
        if not SEMVER.match(v):
            raise ValueError(f"version {v!r} is not a semantic version like 1.2.3")
        return v


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def version_key(version: str) -> tuple:
    """Sort key for semantic versions: a pre-release sorts before its release."""
    m = SEMVER.match(version)
    if not m:
        raise UserError(f"not a semantic version: {version!r}")
    major, minor, patch, pre = m.groups()
    return int(major), int(minor), int(patch), pre is None, pre or ""


def list_versions(registry: Path, name: str) -> list[str]:
    """Published versions of ``name``, oldest first (staging folders are hidden)."""
    folder = Path(registry) / name
    if not folder.is_dir():
        return []
    found = [p.name for p in folder.iterdir() if p.is_dir() and SEMVER.match(p.name)]
    return sorted(found, key=version_key)


def migrate_card(card: dict[str, Any]) -> dict[str, Any]:
    """A card of any known schema as the current schema's fields (a new dict; the input is untouched).

    Schema 1 kept the inference settings inside ``generator`` beside the architecture, and
    named options since retired. They move to ``inference``; a retired option at its off
    value is dropped, and one that was on is a ``ValueError`` that names it.

    Schema 2 had an ``output`` text that nothing read (the generator spec's ``output_nc``
    and ``depth_encoding`` say it), dropped in 3, and called a fit's starting version
    ``started_from``, now ``start_from`` as everywhere else.

    Schema 4 added the optional ``int8`` graph; a schema-3 card reads as one without it. Its ``int8.sample``
    (the photo int8 was checked on) is the card's ``sample`` since 5, when every export began to ship one: every
    engine is checked on it.
    """
    if not isinstance(card, dict):
        raise ValueError("expected a JSON object")
    version = card.get("schema_version", 1)
    if version not in range(1, SCHEMA_VERSION + 1):
        raise ValueError(f"schema_version {version} is not one this reader knows (1 to {SCHEMA_VERSION})")
    card = copy.deepcopy(card)
    if version == 1:
        generator = card.get("generator", {})
        for key, off in RETIRED_GENERATOR_OPTIONS.items():
            if key in generator and generator.pop(key) != off:
                raise ValueError(
                    f"generator.{key} is on, and that option was retired; no current version of rgb2cloud runs "
                    "this card"
                )
        card["inference"] = {key: generator.pop(key) for key in InferenceSettings.model_fields if key in generator}
    if version <= 2:
        card.pop("output", None)
        fit = (card.get("training") or {}).get("fit")
        if isinstance(fit, dict) and "started_from" in fit:
            fit["start_from"] = fit.pop("started_from")
    if version <= 4 and isinstance(card.get("int8"), dict) and "sample" in card["int8"]:
        card["sample"] = card["int8"].pop("sample")
    card["schema_version"] = SCHEMA_VERSION
    return card


def next_version(registry: Path, name: str) -> str:
    """The version to publish next under ``name``: 0.1.0 first, then the newest release's next minor."""
    releases = [v for v in list_versions(registry, name) if "-" not in v]
    if not releases:
        return "0.1.0"
    major, minor, _ = (int(part) for part in releases[-1].split("."))
    return f"{major}.{minor + 1}.0"


def load_card(version_dir: Path) -> ModelCard:
    """Read, migrate and validate ``<version_dir>/card.json``; any problem is a ``CardError`` naming the file."""
    path = Path(version_dir) / CARD_FILE
    try:
        return ModelCard.model_validate(migrate_card(json.loads(path.read_bytes())))
    except FileNotFoundError as e:
        raise CardError(f"{path}: missing") from e
    except ValueError as e:  # json and pydantic errors are ValueErrors too
        raise CardError(f"{path}: not a valid model card: {e}") from e


def verify_files(version_dir: Path, card: ModelCard) -> None:
    """Check that every listed file exists with its recorded sha256, and that the sample and int8 graph the card
    names are among them."""
    if missing := _unlisted(card, card.files):
        raise CardError(f"{Path(version_dir) / CARD_FILE}: it names files it does not list: {missing}")
    for file_name, expected in card.files.items():
        path = Path(version_dir) / file_name
        if not path.is_file():
            raise CardError(f"{path}: listed in the card but missing")
        actual = sha256_file(path)
        if actual != expected:
            raise CardError(f"{path}: sha256 {actual} does not match the card's {expected}")


def _unlisted(card: ModelCard, files: Iterable[str]) -> dict[str, str]:
    """The files the card names (its sample, its int8 graph) that are not among ``files``, by what they are."""
    named = {"sample": card.sample, "int8 graph": card.int8.file if card.int8 else None}
    return {what: file for what, file in named.items() if file is not None and file not in files}


def publish(registry: Path, card: ModelCard, files: dict[str, Path]) -> Path:
    """Copy ``files`` into ``<registry>/<name>/<version>/`` with the card; never overwrite.

    The card's ``files`` digests are recomputed here from what was copied, so a
    card can only ever describe the bytes beside it; a card that names a sample or
    int8 graph not among ``files`` is refused, as every load would refuse it.
    """
    target = Path(registry) / card.name / card.version
    if target.exists():
        raise FileExistsError(f"{target} already exists: versions are immutable, publish a new one")
    if missing := _unlisted(card, files):
        raise CardError(f"{target}: the card names files it is not published with: {missing}")
    created = not target.parent.exists()
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{card.version}.", dir=target.parent))
    try:
        digests = {}
        for file_name, source in files.items():
            shutil.copyfile(source, staging / file_name)
            digests[file_name] = sha256_file(staging / file_name)
        final = card.model_copy(update={"files": digests})
        (staging / CARD_FILE).write_text(final.model_dump_json(indent=2) + "\n")
        os.chmod(staging, 0o755)
        if target.exists():  # lost a race with another publisher
            raise FileExistsError(f"{target} already exists: versions are immutable, publish a new one")
        os.rename(staging, target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if created:  # a failed first version leaves no empty name folder behind
            with contextlib.suppress(OSError):
                target.parent.rmdir()
        raise
    return target
