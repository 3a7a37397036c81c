"""``rgb2cloud-lab``: report, record, diagnose, novelty. Research commands beside the product's CLI."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli.main import run_app
from cli.options import (
    ColourCameraOption,
    Format,
    Frames,
    MaxDepth,
    MinDepth,
    ModelArgument,
    Root,
    parse_colour_camera,
)

app = typer.Typer(help="rgb2cloud-lab: research tooling for rgb2cloud models.", no_args_is_help=True)


@app.command()
def report(
    model: Annotated[Path, typer.Argument(help="the published version folder to report on", exists=True)],
    root: Annotated[Path, typer.Option(help="7-Scenes sequence folder", exists=True, file_okay=False)],
    unseen: Annotated[Path, typer.Option(help="CSV manifest of a scene never trained on", exists=True, dir_okay=False)],
    experiments: Annotated[
        Path | None,
        typer.Option(
            help="YAML file, label -> a checkpoint, version folder or stored record (.json) to compare with it "
            "(paths relative to the current folder)",
            exists=True,
            dir_okay=False,
        ),
    ] = None,
    train_frames: Annotated[str, typer.Option(help="frames the baselines are fitted on")] = "0-799",
    test_frames: Annotated[str, typer.Option(help="frames everything is scored on")] = "850-999",
    out: Annotated[Path, typer.Option(help="folder for quality.md and quality/")] = Path("docs"),
    config: Annotated[
        Path | None, typer.Option(help="the config that trains the model (default configs/NAME-VERSION.yaml)")
    ] = None,
) -> None:
    """Write quality.md: metrics beside the paper and baselines, curve, samples, experiments, an unseen scene."""
    from lab.experiments import read_experiments
    from lab.report import ReportInputs, build_report

    compare = read_experiments(experiments) if experiments else {}
    inputs = ReportInputs(
        model, root, unseen, compare, out, config, experiments, train_frames=train_frames, test_frames=test_frames
    )
    typer.echo(f"wrote {build_report(inputs)}")


@app.command()
def record(
    label: Annotated[str, typer.Argument(help="the report row's label; also names the record file")],
    test: Annotated[Path, typer.Option(help="metrics.json of `rgb2cloud evaluate` on the test split", exists=True)],
    unseen: Annotated[Path, typer.Option(help="metrics.json of `rgb2cloud evaluate` on the unseen frame", exists=True)],
    unseen_manifest: Annotated[Path, typer.Option(help="the --unseen manifest the report runs with", exists=True)],
    config: Annotated[Path, typer.Option(help="the YAML run config it was trained with", exists=True)],
    set_: Annotated[list[str], typer.Option("--set", "-s", help="the training command's overrides")] = [],  # noqa: B006
    source: Annotated[str, typer.Option(help="what was scored, where, and why it is not kept")] = "",
    out: Annotated[Path, typer.Option(help="folder of stored records")] = Path("docs/quality/compared"),
) -> None:
    """Store a run scored elsewhere (say, on a leased GPU) as a record `rgb2cloud-lab report` can compare."""
    from lab.records import store_evaluations

    typer.echo(f"wrote {store_evaluations(label, test, unseen, unseen_manifest, config, set_, source, out)}")


@app.command()
def diagnose(
    model: ModelArgument,
    format: Format,
    root: Root,
    frames: Frames = None,
    min_depth: MinDepth = 0.1,
    max_depth: MaxDepth = 10.0,
    colour_camera: ColourCameraOption = None,
) -> None:
    """Where a model's error is: one wrong distance per view (median scaling) or depth steps (where delta1 fails)."""
    from lab.diagnostics import diagnose_source
    from trainer.config import DataSource

    source = DataSource(format=format, root=root, frames=frames)
    colour = parse_colour_camera(colour_camera) if colour_camera else None
    typer.echo(diagnose_source(model, source, (min_depth, max_depth), colour))


@app.command()
def failures(
    run: Annotated[Path, typer.Argument(help="the --out folder of an `rgb2cloud fit` that has published", exists=True)],
    worst: Annotated[int, typer.Option(min=1, help="how many of the worst views to draw")] = 4,
    out: Annotated[Path | None, typer.Option(help="where views.md and worst.jpg go (default: RUN/failures)")] = None,
) -> None:
    """Where a fit fails: each held-out view scored, the worst drawn beside the sensor's depth."""
    from lab.failures import failure_report

    typer.echo(failure_report(run, worst, out or run / "failures"))


@app.command()
def novelty(
    root: Annotated[Path, typer.Argument(help="a 7-Scenes sequence folder (frame-NNNNNN.pose.txt)", exists=True)],
    splits: Annotated[list[str], typer.Argument(help="TRAIN:HELD_OUT frame ranges, e.g. 0-669:720-799")],
) -> None:
    """How new each held-out slice's views are to its training frames (from camera poses)."""
    from lab.novelty import novelty_table

    typer.echo(novelty_table(root, splits))


def main() -> None:
    run_app(app)
