"""``rgb2cloud fit`` as the benchmarks run it: each fit in its own process, published once, reused after."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
#: The development sites and how they are split (../shared/data/README.md): the recording, then fit's
#: options. aims-lab publishes no intrinsics: its README says to use 7-Scenes-like ones, which only the
#: point clouds depend on.
SITES = {
    "aims-lab": [
        str(DATA / "aims-lab"),
        "--holdout", "160-199", "--gap", "20",
        "--fx", "585", "--fy", "585", "--cx", "320", "--cy", "240",
        "--licence", "aims-lab (CMU-AI-Maker-Space/aims-slam): MIT",
    ],
    "mosd-tabletop": [
        str(DATA / "mosd-tabletop"),
        "--holdout", "test*", "--gap", "0",
        "--licence", "mOSD (Richtsfeld et al., TU Wien): research use",
    ],
}  # fmt: skip


def fit_once(recording: Path, name: str, out: Path, *options: str) -> Path:
    """``rgb2cloud fit RECORDING --name NAME OPTIONS``, published into ``out/registry`` with its run folder under
    ``out/runs``; the published version folder. A fit already published is not run again, so a benchmark run
    a second time adds only its new rows."""
    version = out / "registry" / name / "0.1.0"
    if not version.is_dir():
        args = [str(recording), "--name", name, *options, "--registry", str(out / "registry")]
        subprocess.run(
            [sys.executable, "-m", "cli", "fit", *args, "--out", str(out / "runs" / name)], cwd=REPO, check=True
        )
    return version


def report(table: str, markdown: Path | None, title: str, command: str) -> None:
    """Print a benchmark's table, and write it as a markdown page that names the command that made it."""
    print(table)
    if markdown:
        markdown.parent.mkdir(parents=True, exist_ok=True)
        markdown.write_text(f"# {title}\n\nMade by `{command}`.\n\n{table}")


def bench_arguments(doc: str) -> argparse.Namespace:
    """A fit benchmark's options: the budget of each fit, and where to write the table."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--budget", type=float, default=5.0, help="minutes for each fit")
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    return parser.parse_args()
