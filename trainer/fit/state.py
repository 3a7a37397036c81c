"""A fit's run folder as ``--resume`` reads it: ``fit.json`` (everything decided before training), and what
continues a fit stopped at any moment."""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field

from contract.card import IMAGENET_START, CardError, list_versions, load_card
from contract.geometry import ColourCamera
from trainer.config import RunConfig
from trainer.fit.budget import Plan

#: ``start_from`` of a fit that started from no trained generator: 'imagenet', or 'scratch' in a fit.json written
#: before the ImageNet start was fit's default.
NO_TRAINED_START = (IMAGENET_START, "scratch")


class FitState(BaseModel):
    """Everything a fit decides before training, saved as ``fit.json``: what ``--resume`` continues."""

    #: Drawn once per fit (``new_fit_id``), and written into the card it publishes: the one thing that tells
    #: this fit's version from another fit's of the same name in the same run folder. None in a fit.json
    #: written before fits had ids.
    fit_id: str | None = None
    report: list[str]
    data: str
    format: str
    licence: str
    start_from: str = Field(description="the published version folder training starts from, or 'imagenet'")
    split: dict[str, dict[str, Any]] = Field(description="Split.summary: each part's frames, first and last")
    colour_camera: ColourCamera | None
    plan: Plan
    config: RunConfig
    #: The version folder this fit published, once it has: a finished fit is never resumed into a second one.
    published: str | None = None

    @property
    def start(self) -> Path | None:
        return None if self.start_from in NO_TRAINED_START else Path(self.start_from)


def new_fit_id() -> str:
    return uuid.uuid4().hex


def published_by(state: FitState, registry: Path, name: str) -> Path | None:
    """The version of ``name`` this fit published, if any: the one whose card carries this fit's id.

    Publishing and recording it in fit.json are two steps; a Ctrl-C between them must not make ``--resume``
    publish the same fit again as the next version. An earlier fit of the same name in the same folder
    published under another id, so its version is never taken for this one's. A fit from before ids
    (``fit_id`` None) can only have published a card without one, from its own training folder.
    """
    ours = Path(state.config.train.out_dir).resolve() if state.fit_id is None else None
    for version in reversed(list_versions(registry, name)):
        folder = Path(registry) / name / version
        try:
            card = load_card(folder)
        except CardError:
            continue
        fit = card.training.fit
        if fit is None:
            continue
        if state.fit_id is not None and fit.fit_id == state.fit_id:
            return folder
        out_dir = card.training.config.get("train", {}).get("out_dir")
        if ours is not None and fit.fit_id is None and out_dir and Path(out_dir).resolve() == ours:
            return folder
    return None


def save_state(path: Path, state: FitState) -> None:
    """Write ``fit.json`` whole or not at all: a Ctrl-C mid-write must not leave a file ``--resume`` cannot read."""
    partial = path.with_suffix(".json.partial")
    partial.write_text(state.model_dump_json(indent=2) + "\n")
    partial.replace(path)


def interrupted_hint(run: Path) -> str:
    """What continues a fit stopped at this moment: ``--resume`` once ``fit.json`` holds its plan, else a fresh start.

    The two hints never point at each other: ``--resume`` continues any fit with a ``fit.json``, checkpoint or
    not, and without one the same command starts again over the partial run folder.
    """
    if (run / "fit.json").is_file():
        return "interrupted: the same command with --resume continues it"
    return "interrupted before training began: the same command (without --resume) starts it again"
