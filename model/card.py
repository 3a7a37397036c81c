"""Model cards and the versioned registry. Torch-free: the service loads with this.

A registry is a folder ``<registry>/<name>/<version>/`` holding the exported
generator files and ``card.json``. The card says everything needed to use and
trust the weights: a sha256 per file, the generator config (to rebuild and to
check the weights against), the input and depth encodings, the training camera,
the data and its licences, and the metrics with their split.

Versions are immutable: publishing stages into a hidden folder beside the
target and renames it into place, refusing if the version already exists.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import tempfile
from datetime import datetime
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, field_validator

from model.codec import DepthEncoding
from model.config import ColourCamera, GeneratorConfig

CARD_FILE = "card.json"
ONNX_FILE = "generator.onnx"
TORCHSCRIPT_FILE = "generator.torchscript.pt"
SEMVER = re.compile(r"^(0|[1-9]\d*)\.(0|[1-9]\d*)\.(0|[1-9]\d*)(?:-([0-9A-Za-z.-]+))?$")
NAME = re.compile(r"^[a-z0-9][a-z0-9._-]{0,63}$")


class CardError(ValueError):
    """A card or its files cannot be trusted; the message names the file and the reason."""


class Camera(BaseModel):
    """Intrinsics of the training data, in pixels of a ``width`` x ``height`` image."""

    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    width: int = Field(gt=0)
    height: int = Field(gt=0)


class DataRef(BaseModel):
    """One dataset a model saw, with the frames used and the licence that binds them."""

    name: str
    format: str
    frames: str
    licence: str = Field(min_length=1)


class Metrics(BaseModel):
    """The paper's metrics on a named split, plus the mean point-cloud RMSE."""

    split: str = Field(min_length=1, description="dataset and frames, e.g. 7scenes-redkitchen 850-999")
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


class Training(BaseModel):
    data: list[DataRef] = Field(min_length=1)
    steps: int
    duration_s: float
    hardware: str
    config: dict


class ModelCard(BaseModel):
    model_config = ConfigDict(extra="forbid")

    schema_version: int = 1
    name: str
    version: str
    created: datetime
    files: dict[str, str] = Field(description="file name -> sha256 hex digest")
    generator: GeneratorConfig
    input_multiple: int
    input_encoding: str
    output: str = "1 channel, tanh range [-1, 1]; metres via depth_encoding"
    depth_encoding: DepthEncoding
    camera: Camera
    training: Training
    metrics: list[Metrics] = Field(min_length=1)
    trainer_commit: str
    parity: dict[str, float] = Field(default_factory=dict, description="export vs eager max abs diff")
    derived_from: str | None = Field(
        None,
        description="the published version whose weights these are, exported again with other inference "
        "settings (generator); its training is this card's training",
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
        raise ValueError(f"not a semantic version: {version!r}")
    major, minor, patch, pre = m.groups()
    return int(major), int(minor), int(patch), pre is None, pre or ""


def list_versions(registry: Path, name: str) -> list[str]:
    """Published versions of ``name``, oldest first (staging folders are hidden)."""
    folder = Path(registry) / name
    if not folder.is_dir():
        return []
    found = [p.name for p in folder.iterdir() if p.is_dir() and SEMVER.match(p.name)]
    return sorted(found, key=version_key)


def load_card(version_dir: Path) -> ModelCard:
    path = Path(version_dir) / CARD_FILE
    try:
        return ModelCard.model_validate_json(path.read_bytes())
    except FileNotFoundError as e:
        raise CardError(f"{path}: missing") from e
    except ValueError as e:
        raise CardError(f"{path}: not a valid model card: {e}") from e


def verify_files(version_dir: Path, card: ModelCard) -> None:
    """Check that every listed file exists with its recorded sha256."""
    for file_name, expected in card.files.items():
        path = Path(version_dir) / file_name
        if not path.is_file():
            raise CardError(f"{path}: listed in the card but missing")
        actual = sha256_file(path)
        if actual != expected:
            raise CardError(f"{path}: sha256 {actual} does not match the card's {expected}")


def publish(registry: Path, card: ModelCard, files: dict[str, Path]) -> Path:
    """Copy ``files`` into ``<registry>/<name>/<version>/`` with the card; never overwrite.

    The card's ``files`` digests are recomputed here from what was copied, so a
    card can only ever describe the bytes beside it.
    """
    target = Path(registry) / card.name / card.version
    if target.exists():
        raise FileExistsError(f"{target} already exists: versions are immutable, publish a new one")
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
        raise
    return target
