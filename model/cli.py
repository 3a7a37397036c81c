"""The ``rgb2cloud`` command line: train, evaluate, export, baselines, novelty, calibrate,
report, record, client.

Heavy imports happen inside each command, so ``rgb2cloud --help`` is instant and
the torch-free parts of the project never pay for torch.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from model.config import ColourCamera

# Inference settings: how trained weights are run (``GeneratorConfig.run_as``); unset keeps the model's own.
FlipAverage = Annotated[
    bool | None, typer.Option(help="also run the mirrored image and average (default: as the model has it)")
]
MedianRadius = Annotated[
    int | None,
    typer.Option(
        help="refine the network's output by a colour-weighted median over (2r+1)^2 taps, guided by the photo "
        "(0: off; default: as the model has it)"
    ),
]
MedianSigma = Annotated[float | None, typer.Option(help="the median's colour scale, in the input's [-1, 1] units")]
MedianSpacing = Annotated[int | None, typer.Option(help="pixels between the median's taps, at the working scale")]
UpsampleSigma = Annotated[
    float | None,
    typer.Option(
        help="bring the working-scale output up to the photo's size guided by its colours (joint bilateral "
        "upsampling), with this colour scale in the input's [-1, 1] units (0: plain bilinear; default: as the "
        "model has it)"
    ),
]


def _run_as(
    flip_average: bool | None,
    median_radius: int | None,
    median_sigma: float | None,
    median_spacing: int | None,
    upsample_sigma: float | None,
) -> dict:
    """The inference settings given on the command line (``GeneratorConfig.run_as``); unset ones are left out."""
    given = {
        "flip_average": flip_average,
        "median_radius": median_radius,
        "median_sigma": median_sigma,
        "median_spacing": median_spacing,
        "upsample_sigma": upsample_sigma,
    }
    return {key: value for key, value in given.items() if value is not None}


app = typer.Typer(help="rgb2cloud: metric depth and point clouds from one RGB image.", no_args_is_help=True)


@app.command()
def train(
    config: Annotated[Path, typer.Argument(help="YAML run config", exists=True, dir_okay=False)],
    set_: Annotated[list[str], typer.Option("--set", "-s", help="override, e.g. -s train.steps=2000")] = [],  # noqa: B006
    resume: Annotated[bool, typer.Option(help="continue from <out_dir>/checkpoints/last.pt")] = False,
) -> None:
    """Train the depth cGAN. Runs alone, or under torchrun for DistributedDataParallel."""
    from model.config import load_config
    from model.train import train as run

    summary = run(load_config(config, set_), resume=resume)
    if summary["best"]:
        best = summary["best"]
        typer.echo(f"best validation {best['metrics']} at step {best['step']}")


@app.command()
def evaluate(
    model: Annotated[
        list[Path],
        typer.Argument(
            help="a published version folder, or checkpoints (.pt): several run as one, the mean of their outputs",
            exists=True,
        ),
    ],
    format: Annotated[str, typer.Option(help="7scenes | tum | nyu | csv")],
    root: Annotated[Path, typer.Option(help="dataset folder (or .mat / .csv file)", exists=True)],
    frames: Annotated[str | None, typer.Option(help="7scenes frame ranges, e.g. 850-999")] = None,
    split: Annotated[str, typer.Option(help="nyu: train | test | all")] = "all",
    splits_file: Annotated[Path | None, typer.Option(help="nyu: splits.mat (default: beside the .mat)")] = None,
    out: Annotated[Path, typer.Option(help="folder for metrics.json, metrics.md and plots")] = Path("runs/eval"),
    min_depth: Annotated[float, typer.Option(help="valid ground truth from (m)")] = 0.1,
    max_depth: Annotated[float, typer.Option(help="valid ground truth up to (m)")] = 10.0,
    samples: Annotated[int, typer.Option(help="rows in samples.png")] = 4,
    flip_average: FlipAverage = None,
    median_radius: MedianRadius = None,
    median_sigma: MedianSigma = None,
    median_spacing: MedianSpacing = None,
    upsample_sigma: UpsampleSigma = None,
    median_scaled: Annotated[
        bool,
        typer.Option(
            help="diagnostic: also score each prediction scaled by its ground-truth/predicted median ratio, "
            "and print that ratio's spread (how much of the error is one distance per view)"
        ),
    ] = False,
    where_fails: Annotated[
        bool,
        typer.Option(
            help="diagnostic: also split the delta1 failures between pixels within 3 px of a ground-truth "
            "depth step of over 25% and the rest (blurred edges against wrong surfaces)"
        ),
    ] = False,
    colour_camera: Annotated[
        str | None,
        typer.Option(
            help="for a model trained on registered depth: the colour camera beside the ground truth's depth "
            "camera, as the data config writes it, e.g. '{fx: 528, fy: 528, cx: 315.5, cy: 238.5, "
            "baseline_m: 0.012, roll_deg: 0.55}' (rgb2cloud calibrate); each ground-truth pixel is compared "
            "with the prediction where the photo sees the same point"
        ),
    ] = None,
) -> None:
    """Score a model with the paper's metrics and print the paper's table."""
    from model.config import DataSource
    from model.data.sources import describe, open_source
    from model.evaluate import evaluate_frames, load_predictor, markdown_table, write_report
    from model.failures import where_fails_line

    colour = parse_colour_camera(colour_camera) if colour_camera else None
    predict, label = load_predictor(
        model, _run_as(flip_average, median_radius, median_sigma, median_spacing, upsample_sigma)
    )
    source = DataSource(format=format, root=root, frames=frames, split=split, splits_file=splits_file)
    result, per_image, grid = evaluate_frames(
        predict,
        open_source(source),
        min_m=min_depth,
        max_m=max_depth,
        samples=samples,
        progress=True,
        median_scaled=median_scaled,
        where_fails=where_fails,
        colour_camera=colour,
    )
    if colour:
        label += ", read at the colour camera"
    table = write_report(
        out,
        result,
        per_image,
        grid,
        split=describe(source),
        label=label,
        depth_range=(min_depth, max_depth),
        colour_camera=colour,
    )
    typer.echo(table)
    if median_scaled:
        ratio = result["median_ratio"]
        typer.echo(
            f"\ndiagnostic, not the paper's protocol: ground-truth/predicted median per image "
            f"{ratio['mean']:.3f} +- {ratio['std']:.3f}; with each prediction scaled by it:\n"
            + markdown_table({f"{label}, median-scaled": result["median_scaled"]})
        )
    if where_fails:
        typer.echo("\n" + where_fails_line(result["where_fails"]))
    typer.echo(f"wrote {out}/metrics.json, metrics.md, pc_rmse_curve.png, samples.png")


@app.command()
def export(
    checkpoint: Annotated[
        Path,
        typer.Argument(
            help="a training checkpoint (.pt), or a published version folder: its weights again, with other "
            "inference settings",
            exists=True,
        ),
    ],
    name: Annotated[str, typer.Option(help="model name in the registry")],
    version: Annotated[str, typer.Option(help="semantic version, e.g. 0.1.0; never reused")],
    metrics: Annotated[list[Path], typer.Option(help="metrics.json from evaluate (repeatable)", exists=True)],
    parity_image: Annotated[Path, typer.Option(help="a real RGB image for the parity check", exists=True)],
    registry: Annotated[Path, typer.Option(help="registry folder")] = Path("weights"),
    flip_average: FlipAverage = None,
    median_radius: MedianRadius = None,
    median_sigma: MedianSigma = None,
    median_spacing: MedianSpacing = None,
    upsample_sigma: UpsampleSigma = None,
) -> None:
    """Export ONNX + TorchScript, check parity with eager PyTorch, publish a version."""
    from model.card import load_card
    from model.export import export_and_publish

    run_as = _run_as(flip_average, median_radius, median_sigma, median_spacing, upsample_sigma)
    target = export_and_publish(checkpoint, registry, name, version, metrics, parity_image, run_as)
    card = load_card(target)
    for file_name, digest in card.files.items():
        typer.echo(f"{file_name}  sha256 {digest}")
    for check, diff in card.parity.items():
        typer.echo(f"parity {check}: max abs diff {diff:.2e}")
    typer.echo(f"published {target}")


@app.command()
def baselines(
    format: Annotated[str, typer.Option(help="7scenes | tum | nyu | csv")],
    root: Annotated[Path, typer.Option(help="dataset folder (or .mat / .csv file)", exists=True)],
    train_frames: Annotated[str, typer.Option(help="frames the baselines are fitted on, e.g. 0-799")],
    test_frames: Annotated[str, typer.Option(help="frames they are scored on, e.g. 850-999")],
    out: Annotated[Path | None, typer.Option(help="also write baselines.json here")] = None,
    min_depth: Annotated[float, typer.Option(help="valid ground truth from (m)")] = 0.1,
    max_depth: Annotated[float, typer.Option(help="valid ground truth up to (m)")] = 10.0,
) -> None:
    """Score the image-free baselines (train median; per-pixel train median) on a test split."""
    import json

    from model.baselines import fit_baselines, score_baselines
    from model.config import DataSource
    from model.data.sources import describe, open_source
    from model.evaluate import PAPER_TUM, markdown_table

    train_source = DataSource(format=format, root=root, frames=train_frames)
    test_source = DataSource(format=format, root=root, frames=test_frames)
    fitted = fit_baselines(open_source(train_source))
    results = score_baselines(fitted, open_source(test_source), min_depth, max_depth)
    rows = {
        f"constant {fitted['constant']:.2f} m (train median)": results["constant"],
        "per-pixel train median": results["per_pixel"],
        "paper (TUM, Table 2)": PAPER_TUM,
    }
    typer.echo(f"fitted on {describe(train_source)}, scored on {describe(test_source)}\n")
    typer.echo(markdown_table(rows))
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        payload = {
            "train": describe(train_source),
            "test": describe(test_source),
            "constant_m": fitted["constant"],
            "depth_range_m": [min_depth, max_depth],
            "metrics": results,
        }
        (out / "baselines.json").write_text(json.dumps(payload, indent=2) + "\n")


@app.command()
def novelty(
    root: Annotated[Path, typer.Argument(help="a 7-Scenes sequence folder (frame-NNNNNN.pose.txt)", exists=True)],
    splits: Annotated[list[str], typer.Argument(help="TRAIN:HELD_OUT frame ranges, e.g. 0-669:720-799")],
) -> None:
    """How new each held-out slice's views are to its training frames (from camera poses)."""
    from model.novelty import read_poses, view_novelty

    pairs = [split.partition(":") for split in splits]
    for split, (train_frames, sep, held_out) in zip(splits, pairs, strict=True):
        if not sep or not train_frames or not held_out:
            raise typer.BadParameter(f"{split!r}: expected TRAIN:HELD_OUT, e.g. 0-669:720-799")
    typer.echo("| train | held out | frames | closest training view: distance (m) | turn (deg) |")
    typer.echo("|---|---|---|---|---|")
    for train_frames, _, held_out in pairs:
        gap = view_novelty(read_poses(root, train_frames), read_poses(root, held_out))
        typer.echo(f"| {train_frames} | {held_out} | {gap.frames} | {gap.distance_m:.2f} | {gap.angle_deg:.1f} |")


@app.command()
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
    from model.config import ColourCamera
    from model.data.frames import parse_frame_ranges
    from model.data.sevenscenes import SevenScenesReader
    from model.registration import alignment, fit_colour_camera

    others = [parse_colour_camera(text, "--compare") for text in compare]
    chosen = parse_frame_ranges(frames)[::every]
    reader = SevenScenesReader(root, ",".join(str(n) for n in chosen))
    sample = [reader[i] for i in range(len(reader))]
    depth_camera = sample[0].intrinsics
    unregistered = ColourCamera(fx=depth_camera.fx, fy=depth_camera.fy, cx=depth_camera.cx, cy=depth_camera.cy)
    start = unregistered.model_copy(update={"fx": fx, "fy": fx})
    fitted, score = fit_colour_camera(sample, start)
    typer.echo(f"{len(sample)} frames of {frames}, every {every}th")
    typer.echo(f"alignment as recorded (same camera): {alignment(sample, unregistered):.4f}")
    for text, camera in zip(compare, others, strict=True):
        typer.echo(f"alignment of {text}: {alignment(sample, camera):.4f}")
    typer.echo(f"alignment fitted: {score:.4f}")
    typer.echo(f"colour_camera: {fitted.flow()}")


@app.command()
def report(
    model: Annotated[Path, typer.Argument(help="the published version folder to report on", exists=True)],
    root: Annotated[Path, typer.Option(help="7-Scenes sequence folder", exists=True, file_okay=False)],
    unseen: Annotated[Path, typer.Option(help="CSV manifest of a scene never trained on", exists=True, dir_okay=False)],
    compare: Annotated[
        list[str], typer.Option(help="LABEL=PATH: a checkpoint, version or stored score (.json) to show beside it")
    ] = [],  # noqa: B006
    train_frames: Annotated[str, typer.Option(help="frames the baselines are fitted on")] = "0-799",
    test_frames: Annotated[str, typer.Option(help="frames everything is scored on")] = "850-999",
    out: Annotated[Path, typer.Option(help="folder for quality.md and quality/")] = Path("docs"),
    recipe: Annotated[
        Path | None, typer.Option(help="shell script of the training commands, quoted in quality.md", exists=True)
    ] = None,
) -> None:
    """Write quality.md: metrics beside the paper and baselines, curve, samples, ablation, an unseen scene."""
    from model.report import ReportInputs, build_report

    pairs = {}
    for item in compare:
        name, sep, path = item.rpartition("=")
        if not sep or not name or not Path(path).exists():
            raise typer.BadParameter(
                f"--compare {item!r}: expected LABEL=PATH to an existing checkpoint, version or stored score"
            )
        pairs[name] = Path(path)
    inputs = ReportInputs(
        model, root, unseen, pairs, out, recipe=recipe, train_frames=train_frames, test_frames=test_frames
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
    """Store a run scored elsewhere (say, on a leased GPU) as a record `rgb2cloud report --compare` reads."""
    import json

    from model.config import load_config
    from model.data.manifest import ManifestReader
    from model.scores import now, record_from_evaluations, record_path, write_record

    stored = record_from_evaluations(
        json.loads(test.read_text()),
        json.loads(unseen.read_text()),
        unseen_manifest=str(unseen_manifest),
        unseen_images=len(ManifestReader(unseen_manifest)),
        config=load_config(config, set_).model_dump(mode="json"),
        source=source or str(test.parent),
        scored=f"scored by rgb2cloud evaluate, stored {now()} by rgb2cloud record",
    )
    path = record_path(out, label)
    write_record(path, stored)
    typer.echo(f"wrote {path}")


@app.command()
def client(
    source: Annotated[Path, typer.Argument(help="an image, or a folder of images", exists=True)],
    out: Annotated[Path | None, typer.Option("-o", "--out", help="output folder (default: beside each input)")] = None,
    depth: Annotated[bool, typer.Option(help="write <name>.depth.png (16-bit mm)")] = True,
    pointcloud: Annotated[bool, typer.Option(help="write <name>.ply")] = False,
    url: Annotated[str, typer.Option(help="service base URL")] = "http://127.0.0.1:8000",
    timeout: Annotated[float, typer.Option(help="seconds per request")] = 60.0,
    retries: Annotated[int, typer.Option(help="retries on 503 or a dropped connection")] = 5,
    stride: Annotated[int, typer.Option(help="point cloud: keep every stride-th row and column")] = 1,
) -> None:
    """Send images to a running service and save depth PNGs and/or PLY point clouds."""
    from app.client import ClientOptions, run

    kinds = [k for k, on in (("depth", depth), ("pointcloud", pointcloud)) if on]
    if not kinds:
        raise typer.BadParameter("nothing to do: enable --depth and/or --pointcloud")
    options = ClientOptions(url=url, timeout_s=timeout, retries=retries, cloud_params={"stride": stride})
    failed = 0
    for image, outcome in run(source, kinds, out, options):
        failed += outcome.startswith("error")
        typer.echo(f"{image}: {outcome}", err=outcome.startswith("error"))
    if failed:
        raise typer.Exit(1)


def parse_colour_camera(text: str, option: str = "--colour-camera") -> ColourCamera:
    """A colour camera option as YAML flow, the way a data source's ``colour_camera`` is written."""
    import yaml
    from pydantic import ValidationError

    from model.config import ColourCamera

    try:
        return ColourCamera.model_validate(yaml.safe_load(text))
    except (yaml.YAMLError, ValidationError) as e:
        raise typer.BadParameter(f"{option} {text!r}: {e}") from e


def main() -> None:
    """Run the CLI; mistakes a user can fix (bad paths, configs, versions) print one line, exit 1."""
    try:
        app()
    except (OSError, ValueError) as e:
        typer.echo(f"error: {e}", err=True)
        raise SystemExit(1) from None
