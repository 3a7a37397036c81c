"""The runs a report compares with the published model, and what each changed against it.

``docs/quality/experiments.yaml`` names them (label -> checkpoint, version or stored
record); the report shows each one's scores and one table row of what its training
config changed, so the history of what was tried stays a compact table, not a diary.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from contract.errors import UserError
from lab.records import ScoreRecord, is_record, record_config


def read_experiments(path: Path) -> dict[str, Path]:
    """The compared runs a YAML file names (label -> path), each checked to exist."""
    entries = yaml.safe_load(Path(path).read_text()) or {}
    if not isinstance(entries, dict):
        raise UserError(f"{path}: expected a mapping of label -> path")
    missing = [str(p) for p in entries.values() if not Path(p).exists()]
    if missing:
        raise UserError(f"{path}: no such checkpoint, version or record: {', '.join(missing)}")
    return {str(label): Path(p) for label, p in entries.items()}


def config_diff(base: dict, other: dict, prefix: str = "") -> list[str]:
    """``key: base -> other`` for every leaf that differs (output folders ignored)."""
    lines = []
    for key in sorted(set(base) | set(other)):
        a, b = base.get(key), other.get(key)
        name = f"{prefix}{key}"
        if isinstance(a, dict) and isinstance(b, dict):
            lines += config_diff(a, b, name + ".")
        elif a != b and key != "out_dir":
            lines.append(f"`{name}`: {_short(a)} → {_short(b)}")
    return lines


def _short(value: object) -> str:
    """A config value for a table cell: data sources by their frames, not their whole entry."""
    if value is None:
        return "(default)"
    if isinstance(value, list) and value and all(isinstance(v, dict) and "format" in v for v in value):
        parts = []
        for source in value:
            registered = ", registered" if source.get("colour_camera") else ""
            parts.append(f"{Path(str(source['root'])).name} {source.get('frames') or source.get('split')}{registered}")
        return "[" + "; ".join(parts) + "]"
    return str(value)


def experiments_section(base_config: dict, records: dict[str, ScoreRecord], paths: dict[str, Path]) -> list[str]:
    """One row per compared run: what changed against the published model, and what it scored.

    ``paths`` are the compared paths relative to the report's folder, for links.
    """
    lines = [
        "## Experiments",
        "",
        "Each compared run above, by what its training differed in from the published model's (config keys, "
        "published → compared; *retired* marks an option measured, not kept, and since removed from the code). "
        "Stored records are in `docs/quality/compared/`, each naming the checkpoint it was scored from.",
        "",
        "| run | what changed | REL | δ1 |",
        "|---|---|---|---|",
    ]
    for name, record in records.items():
        config, retired = record_config(record.config)
        changes = [f"`{key}`: {value} (retired)" for key, value in retired.items()]
        changes += config_diff(base_config, config) or ([] if retired else ["(same training config)"])
        source = f"[record]({paths[name]})" if is_record(paths[name]) else f"`{paths[name]}`"
        lines.append(
            f"| {name} ({source}) | {'; '.join(changes)} | {record.test['rel']:.3f} | {record.test['delta1']:.3f} |"
        )
    return [*lines, ""]
