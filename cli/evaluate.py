"""``rgb2cloud evaluate``, ``baselines`` and ``calibrate``: scores of a model, of no model, and of a colour camera."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from cli.options import (
    ColourCameraOption,
    Cx,
    Cy,
    DepthScale,
    Format,
    Frames,
    Fx,
    Fy,
    Inference,
    MaxDepth,
    MinDepth,
    ModelArgument,
    Root,
    parse_colour_camera,
)

if TYPE_CHECKING:
    from recordings.folders import CameraFile


def evaluate(
    model: ModelArgument,
    format: Format,
    root: Root,
    frames: Frames = None,
    split: Annotated[str, typer.Option(help="nyu: train | test | all")] = "all",
    splits_file: Annotated[Path | None, typer.Option(help="nyu: splits.mat (default: beside the .mat)")] = None,
    out: Annotated[Path, typer.Option(help="folder for metrics.json, metrics.md and plots")] = Path("runs/eval"),
    min_depth: MinDepth = 0.1,
    max_depth: MaxDepth = 10.0,
    samples: Annotated[int, typer.Option(help="rows in samples.png")] = 4,
    inference: Inference = [],  # noqa: B006
    colour_camera: ColourCameraOption = None,
    precision: Annotated[str, typer.Option(help="fp32; bf16 (openvino, with bf16 units); int8 (its graph)")] = "fp32",
    engine: Annotated[str, typer.Option(help="onnxruntime (the reference) or openvino")] = "onnxruntime",
    fx: Fx = None,
    fy: Fy = None,
    cx: Cx = None,
    cy: Cy = None,
    depth_scale: DepthScale = None,
) -> None:
    """Score a model with the paper's metrics and print the paper's table."""
    camera = recording_camera(format, fx, fy, cx, cy, depth_scale)
    from contract.spec import parse_inference_options
    from trainer.config import DataSource
    from trainer.evaluate import evaluate_source

    source = DataSource(format=format, root=root, frames=frames, split=split, splits_file=splits_file, camera=camera)
    colour = parse_colour_camera(colour_camera) if colour_camera else None
    changes, depth_range = parse_inference_options(inference), (min_depth, max_depth)
    table = evaluate_source(model, source, out, changes, depth_range, samples, colour, precision, engine)
    typer.echo(table)
    typer.echo(f"wrote {out}/metrics.json, metrics.md, pc_rmse_curve.png, samples.png")


def recording_camera(
    format: str, fx: float | None, fy: float | None, cx: float | None, cy: float | None, depth_scale: float | None
) -> CameraFile | None:
    """The camera the command line gives a recording (None: none given), refused in one line for a layout whose
    reader keeps its own (7-Scenes, NYU), before any model or recording loads."""
    from contract.errors import UserError
    from recordings.folders import CameraFile

    camera = CameraFile(fx, fy, cx, cy, depth_scale)
    if camera == CameraFile():
        return None
    if format in ("7scenes", "nyu"):
        raise UserError(f"--fx, --fy, --cx, --cy and --depth-scale: a {format} recording's camera is its own")
    return camera


def baselines(
    format: Format,
    root: Root,
    train_frames: Annotated[str, typer.Option(help="frames the baselines are fitted on, e.g. 0-799")],
    test_frames: Annotated[str, typer.Option(help="frames they are scored on, e.g. 850-999")],
    out: Annotated[Path | None, typer.Option(help="also write baselines.json here")] = None,
    min_depth: MinDepth = 0.1,
    max_depth: MaxDepth = 10.0,
    fx: Fx = None,
    fy: Fy = None,
    cx: Cx = None,
    cy: Cy = None,
    depth_scale: DepthScale = None,
) -> None:
    """Score the image-free baselines (train median; per-pixel train median) on a test split."""
    camera = recording_camera(format, fx, fy, cx, cy, depth_scale)
    from trainer.baselines import baselines_table
    from trainer.config import DataSource

    train_source = DataSource(format=format, root=root, frames=train_frames, camera=camera)
    test_source = DataSource(format=format, root=root, frames=test_frames, camera=camera)
    typer.echo(baselines_table(train_source, test_source, (min_depth, max_depth), out))


def calibrate(
    root: Annotated[Path, typer.Argument(help="a 7-Scenes sequence folder", exists=True, file_okay=False)],
    frames: Annotated[str, typer.Option(help="frames to fit on (train frames only)")] = "0-799",
    every: Annotated[int, typer.Option(help="use every Nth of those frames", min=1)] = 40,
    fx: Annotated[float, typer.Option(help="starting colour focal length (px)")] = 525.0,
    compare: Annotated[
        list[str],
        typer.Option(
            help="a colour camera (YAML flow, as printed) whose alignment on the same frames is printed "
            "too: on frames the fit did not use, it says whether one fitted camera generalises better"
        ),
    ] = [],  # noqa: B006
) -> None:
    """Fit where the colour camera sits beside the depth camera, from colour edges and depth steps."""
    from recordings.registration import calibrate_sequence

    others = {text: parse_colour_camera(text, "--compare") for text in compare}
    for line in calibrate_sequence(root, frames, every, fx, others):
        typer.echo(line)
