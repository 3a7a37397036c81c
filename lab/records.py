"""Stored scores of compared runs, so a report outlives the checkpoints it compared.

A run's checkpoints live in ``runs/``, which is never committed and does not survive
a fresh clone, while the report's ablation compares a dozen of them. Each time
``rgb2cloud report`` scores a checkpoint or a version, it writes a record here: the
run's full training config, the metrics on the test split and on the unseen scene,
and exactly what they were scored on. A later report takes the record in place of
the checkpoint (``--compare LABEL=docs/quality/compared/NAME.json``) and refuses it
when the frames, depth range or unseen manifest differ, so a stored row is always
the row the checkpoint would give.

A run trained where its checkpoint cannot be kept (a leased GPU whose disk goes
back with it) is scored there by ``rgb2cloud evaluate``, and ``rgb2cloud-lab record``
turns those two metrics.json files into the same kind of record.

Records are history: a record's config may turn on an option that has since been
retired (``trainer.config.RETIRED_OPTIONS``). ``record_config`` reads it all the same,
naming those options apart, so the report can still say what each experiment changed.
"""

from __future__ import annotations

import json
import re
from datetime import UTC, datetime
from pathlib import Path

from pydantic import BaseModel

from contract.errors import UserError
from trainer.config import RETIRED_OPTIONS, complete_config, retired_options_on


class ScoreRecord(BaseModel):
    """One compared model's scores and the exact conditions they were measured under."""

    source: str
    config: dict
    split: str
    min_m: float
    max_m: float
    unseen: str
    test: dict
    unseen_metrics: dict
    #: Per-image point-cloud RMSE on the test split, for the curve (None: not kept).
    pc_rmse: list[float] | None = None
    scored: str


def is_record(path: Path) -> bool:
    return path.suffix == ".json"


def record_path(folder: Path, label: str) -> Path:
    """A file name from the label: lower case, runs of other characters turned into one '-'."""
    slug = re.sub(r"[^a-z0-9.]+", "-", label.lower()).strip("-")[:150]
    return folder / f"{slug}.json"


def write_record(path: Path, record: ScoreRecord) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record.model_dump(), indent=2) + "\n")


def read_record(path: Path, split: str, min_m: float, max_m: float, unseen: str) -> ScoreRecord:
    """Load a record, refusing one scored under other conditions than this report's."""
    record = ScoreRecord.model_validate_json(Path(path).read_text())
    wanted = {"split": split, "min_m": min_m, "max_m": max_m, "unseen": unseen}
    stored = {key: getattr(record, key) for key in wanted}
    if stored != wanted:
        raise UserError(f"{path}: scored on {stored}, but this report scores on {wanted}; re-score its checkpoint")
    return record


#: Diagnostics a lab evaluation adds; the report's rows hold the paper's protocol alone.
_DIAGNOSTICS = ("median_scaled", "median_ratio", "where_fails")


def record_config(config: dict) -> tuple[dict, dict]:
    """A stored run config completed in today's shape, and the retired options it turned on.

    The retired options are set back to off before the config is completed, so the
    rest of it reads like any current config; the second value says what they were.
    """
    on = retired_options_on(config)
    current = json.loads(json.dumps(config))
    for path in RETIRED_OPTIONS:
        if ".".join(path) in on:
            node = current
            for part in path[:-1]:
                node = node[part]
            del node[path[-1]]
    return complete_config(current), on


def record_from_evaluations(
    test: dict,
    unseen: dict,
    *,
    unseen_manifest: str,
    unseen_images: int,
    config: dict,
    source: str,
    scored: str,
) -> ScoreRecord:
    """A record from two ``rgb2cloud evaluate`` outputs: the test split and the unseen manifest.

    ``unseen_manifest`` is the manifest path the report is run with, holding
    ``unseen_images`` rows; the evaluation may have read a copy of it elsewhere,
    which is why it is named here, not read from the file. Both evaluations must
    share one depth range, as the report's rows do.
    """
    if test["depth_range_m"] != unseen["depth_range_m"]:
        raise UserError(f"test scored on {test['depth_range_m']} m, unseen on {unseen['depth_range_m']} m")
    frames = unseen["metrics"]["images"]
    if frames != unseen_images:
        raise UserError(f"the unseen evaluation scored {frames} frame(s), {unseen_manifest} has {unseen_images}")
    min_m, max_m = test["depth_range_m"]

    def protocol(metrics: dict) -> dict:
        return {key: value for key, value in metrics.items() if key not in _DIAGNOSTICS}

    return ScoreRecord(
        source=source,
        config=config,
        split=test["split"],
        min_m=min_m,
        max_m=max_m,
        unseen=unseen_manifest,
        test=protocol(test["metrics"]),
        unseen_metrics=protocol(unseen["metrics"]),
        pc_rmse=[row["pc_rmse"] for row in test["per_image"]],
        scored=scored,
    )


def now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%d")


def store_evaluations(
    label: str,
    test: Path,
    unseen: Path,
    unseen_manifest: Path,
    config: Path,
    overrides: list[str],
    source: str,
    out: Path,
) -> Path:
    """``rgb2cloud-lab record``: two evaluate outputs and the run's config, stored as a record; returns its path."""
    from recordings.manifest import ManifestReader
    from trainer.config import load_config

    stored = record_from_evaluations(
        json.loads(test.read_text()),
        json.loads(unseen.read_text()),
        unseen_manifest=str(unseen_manifest),
        unseen_images=len(ManifestReader(unseen_manifest)),
        config=load_config(config, overrides).model_dump(mode="json"),
        source=source or str(test.parent),
        scored=f"scored by rgb2cloud evaluate, stored {now()} by rgb2cloud-lab record",
    )
    path = record_path(out, label)
    write_record(path, stored)
    return path
