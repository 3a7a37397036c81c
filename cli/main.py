"""The ``rgb2cloud`` command line: fit, train, evaluate, export, baselines, calibrate, client, stream.

Each command parses its options, calls one function of the trainer or the client,
and prints. Heavy imports happen inside each command, so ``rgb2cloud --help`` is
instant and ``rgb2cloud client`` works in the torch-free serving install.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from cli.stream import stream
from recordings.frames import DEFAULT_MAX_FRAMES  # numpy and PIL only: the serving install has them

if TYPE_CHECKING:
    from contract.geometry import ColourCamera

Inference = Annotated[
    list[str],
    typer.Option(
        help="KEY=VALUE: run the weights with this inference setting instead of the model's own, e.g. "
        "median_radius=0 (repeatable; the settings are contract.spec.InferenceSettings)"
    ),
]
ColourCameraOption = Annotated[
    str | None,
    typer.Option(
        help="for a model trained on registered depth: the colour camera beside the ground truth's depth "
        "camera, as the data config writes it, e.g. '{fx: 530, fy: 530, cx: 314.5, cy: 239, baseline_m: 0.009}' "
        "(rgb2cloud calibrate); each ground-truth pixel is compared with the prediction where the photo sees "
        "the same point"
    ),
]

PrecisionOption = Annotated[
    str,
    typer.Option(
        help="fp32: the fp32 graphs; int8: also an int8 ONNX graph beside them, calibrated on the model's "
        "training frames (the service serves either: RGB2CLOUD_PRECISION, or precision= per request)"
    ),
]


def checked(option: str, value: str, *allowed: str) -> str:
    """An option's value if it is one of ``allowed``, or a one-line error."""
    if value not in allowed:
        raise typer.BadParameter(f"{option} {value!r}: expected {', '.join(allowed[:-1])} or {allowed[-1]}")
    return value


ModelArgument = Annotated[Path, typer.Argument(help="a published version folder, or a checkpoint (.pt)", exists=True)]
Format = Annotated[str, typer.Option(help="7scenes | tum | nyu | csv | folders")]
Root = Annotated[Path, typer.Option(help="dataset folder (or .mat / .csv file)", exists=True)]
Frames = Annotated[
    str | None, typer.Option(help="7scenes frame numbers, e.g. 850-999; other layouts: names, globs or index ranges")
]
MinDepth = Annotated[float, typer.Option(help="valid ground truth from (m)")]
MaxDepth = Annotated[float, typer.Option(help="valid ground truth up to (m)")]
REGISTRY_HELP = "registry to publish into (default: $RGB2CLOUD_REGISTRY, else ~/.local/share/rgb2cloud/models)"

app = typer.Typer(help="rgb2cloud: metric depth and point clouds from one RGB image.", no_args_is_help=True)
app.command()(stream)


@app.command()
def train(
    config: Annotated[Path, typer.Argument(help="YAML run config", exists=True, dir_okay=False)],
    set_: Annotated[list[str], typer.Option("--set", "-s", help="override, e.g. -s train.steps=2000")] = [],  # noqa: B006
    resume: Annotated[bool, typer.Option(help="continue from <out_dir>/checkpoints/last.pt")] = False,
) -> None:
    """Train the depth cGAN. Runs alone, or under torchrun for DistributedDataParallel."""
    from trainer.config import load_config
    from trainer.train import train as run

    summary = run(load_config(config, set_), resume=resume)
    if summary.best:
        typer.echo(f"best validation {summary.best.metrics} at step {summary.best.step}")


@app.command()
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
) -> None:
    """Score a model with the paper's metrics and print the paper's table."""
    from contract.spec import parse_inference_options
    from trainer.config import DataSource
    from trainer.evaluate import evaluate_source

    source = DataSource(format=format, root=root, frames=frames, split=split, splits_file=splits_file)
    colour = parse_colour_camera(colour_camera) if colour_camera else None
    changes, depth_range = parse_inference_options(inference), (min_depth, max_depth)
    table = evaluate_source(model, source, out, changes, depth_range, samples, colour, precision, engine)
    typer.echo(table)
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
    registry: Annotated[Path | None, typer.Option(help=REGISTRY_HELP)] = None,
    inference: Inference = [],  # noqa: B006
    precision: PrecisionOption = "fp32",
) -> None:
    """Export ONNX + TorchScript (and int8 ONNX), check parity with eager PyTorch, publish a version."""
    from app.settings import Settings
    from contract.card import load_card
    from contract.registries import Registries
    from contract.runtime import agreement_line
    from contract.spec import parse_inference_options
    from trainer.export import export_and_publish, metrics_from_report

    settings = Settings()
    registry = registry or settings.registry
    Registries(settings.registry, settings.bundled_registry).check_new_name(name, registry)
    changes = parse_inference_options(inference)
    scores = [metrics_from_report(path) for path in metrics]
    target = export_and_publish(
        checkpoint,
        registry,
        name,
        version,
        scores,
        parity_image,
        changes,
        precision=checked("--precision", precision, "fp32", "int8"),
    )
    card = load_card(target)
    for file_name, digest in card.files.items():
        typer.echo(f"{file_name}  sha256 {digest}")
    for check, diff in card.parity.items():
        typer.echo(f"parity {check}: max abs diff {diff:.2e}")
    if card.int8:
        typer.echo(f"parity int8 (the worse of the parity photo and its double): {agreement_line(card.int8.parity)}")
    typer.echo(f"published {target}")


# fit's longer options, named here so that the command reads as its list of options.
FROM_HELP = (
    "a version folder, NAME[:VERSION] of a registry model, or 'imagenet' (ImageNet's Lite0 encoder, frozen, under a "
    "fresh decoder) (default: the bundled base)"
)
FitFrom = Annotated[str | None, typer.Option("--from", help=FROM_HELP)]
FitFormat = Annotated[
    str | None,
    typer.Option(help="folders|tum|7scenes|nyu|csv|rosbag|azurekinect|strayscanner|record3d (default: detected)"),
]
Holdout = Annotated[
    str | None, typer.Option(help="held-out frames instead of the last 20%: names, globs or ranges, e.g. 'test*'")
]
Gap = Annotated[int | None, typer.Option(help="frames dropped next to the held-out ones (default 5%)", min=0)]
DepthTopic = Annotated[
    str | None, typer.Option(help="a bag's depth image topic (default: found; aligned to colour preferred)")
]
MaxGapMs = Annotated[
    float | None,
    typer.Option(help="a bag's or Kinect file's colour and depth further apart than this are no pair (20)", min=0),
]
MinConfidence = Annotated[
    int | None,
    typer.Option(help="Stray Scanner, Record3D: keep depth pixels of this LiDAR confidence and up (2)", min=0, max=2),
]
Register = Annotated[
    str, typer.Option(help="auto: register depth to colour when a fitted colour camera aligns better; yes; no")
]
RecipeChanges = Annotated[
    list[str], typer.Option("--set", "-s", help="change the start's recipe, e.g. -s loss.l1_depth=50 (repeatable)")
]
Steps = Annotated[
    int | None,
    typer.Option(help="train exactly this many steps, however long they take (default: the budget's)", min=1),
]


@app.command()
def fit(
    data: Annotated[Path, typer.Argument(help="the recording: a folder (color/ + depth/, TUM, 7-Scenes) or a file")],
    name: Annotated[str, typer.Option(help="the model's name in the registry")],
    licence: Annotated[str, typer.Option(help="the terms the recording may be used under (required)")],
    budget: Annotated[float, typer.Option(help="minutes, wall clock, for the whole command", min=1)] = 30.0,
    from_: FitFrom = None,
    registry: Annotated[Path | None, typer.Option(help=REGISTRY_HELP)] = None,
    format: FitFormat = None,
    fx: Annotated[float | None, typer.Option(help="focal length x in pixels (overrides intrinsics.json)")] = None,
    fy: Annotated[float | None, typer.Option(help="focal length y in pixels")] = None,
    cx: Annotated[float | None, typer.Option(help="principal point x in pixels")] = None,
    cy: Annotated[float | None, typer.Option(help="principal point y in pixels")] = None,
    depth_scale: Annotated[float | None, typer.Option(help="raw depth units per metre (1000: millimetres)")] = None,
    holdout: Holdout = None,
    gap: Gap = None,
    color_topic: Annotated[str | None, typer.Option(help="a bag's colour image topic (default: found)")] = None,
    depth_topic: DepthTopic = None,
    max_gap_ms: MaxGapMs = None,
    min_confidence: MinConfidence = None,
    every: Annotated[int, typer.Option(help="keep every Nth pair of a long recording", min=1)] = 1,
    max_frames: Annotated[
        int,
        typer.Option(
            help="keep at most this many pairs, evenly spread, and write only those (0: all); "
            "the default is about what a 30-minute CPU fit can use",
            min=0,
        ),
    ] = DEFAULT_MAX_FRAMES,
    register: Register = "auto",
    out: Annotated[Path | None, typer.Option(help="run folder (default runs/fit/NAME)")] = None,
    resume: Annotated[bool, typer.Option(help="continue an interrupted fit from its last checkpoint")] = False,
    set_: RecipeChanges = [],  # noqa: B006
    steps: Steps = None,
    precision: PrecisionOption = "fp32",
) -> None:
    """Fit a model of your space from a short RGB-D recording, score it honestly, and publish it."""
    from app.settings import Settings
    from cli.service import service_url
    from recordings.folders import CameraFile
    from recordings.formats import ReadOptions
    from trainer.fit.state import interrupted_hint
    from trainer.fit.workflow import FitOptions
    from trainer.fit.workflow import fit as run

    if register not in ("auto", "yes", "no"):
        raise typer.BadParameter(f"--register {register!r}: expected auto, yes or no")
    settings = Settings()
    options = FitOptions(
        data=data,
        name=name,
        licence=licence,
        service_url=service_url(settings),
        budget_min=budget,
        start_from=from_,
        registry=registry or settings.registry,
        bundled=settings.bundled_registry,
        format=format,
        read=ReadOptions(
            CameraFile(fx, fy, cx, cy, depth_scale),
            color_topic,
            depth_topic,
            None if max_gap_ms is None else max_gap_ms / 1000,
            min_confidence,
            every,
            max_frames or None,
        ),
        holdout=holdout,
        gap_frames=gap,
        registration=register,
        out=out,
        resume=resume,
        overrides=set_,
        steps=steps,
        precision=checked("--precision", precision, "fp32", "int8"),
    )
    try:
        run(options, typer.echo)
    except KeyboardInterrupt:
        typer.echo(interrupted_hint(options.run_dir), err=True)
        raise typer.Exit(130) from None


@app.command()
def baselines(
    format: Format,
    root: Root,
    train_frames: Annotated[str, typer.Option(help="frames the baselines are fitted on, e.g. 0-799")],
    test_frames: Annotated[str, typer.Option(help="frames they are scored on, e.g. 850-999")],
    out: Annotated[Path | None, typer.Option(help="also write baselines.json here")] = None,
    min_depth: MinDepth = 0.1,
    max_depth: MaxDepth = 10.0,
) -> None:
    """Score the image-free baselines (train median; per-pixel train median) on a test split."""
    from trainer.baselines import baselines_table
    from trainer.config import DataSource

    train_source = DataSource(format=format, root=root, frames=train_frames)
    test_source = DataSource(format=format, root=root, frames=test_frames)
    typer.echo(baselines_table(train_source, test_source, (min_depth, max_depth), out))


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
    from recordings.registration import calibrate_sequence

    others = {text: parse_colour_camera(text, "--compare") for text in compare}
    for line in calibrate_sequence(root, frames, every, fx, others):
        typer.echo(line)


@app.command()
def client(
    source: Annotated[Path, typer.Argument(help="an image, or a folder of images", exists=True)],
    out: Annotated[Path | None, typer.Option("-o", "--out", help="output folder (default: beside each input)")] = None,
    depth: Annotated[bool, typer.Option(help="write <name>.depth.png (16-bit mm)")] = True,
    pointcloud: Annotated[bool, typer.Option(help="write <name>.ply")] = False,
    url: Annotated[
        str | None, typer.Option(help="service base URL (default: RGB2CLOUD_HOST and RGB2CLOUD_PORT, as make serve)")
    ] = None,
    timeout: Annotated[float, typer.Option(help="seconds per request")] = 60.0,
    retries: Annotated[int, typer.Option(help="retries on 503 or a dropped connection")] = 5,
    stride: Annotated[int, typer.Option(help="point cloud: keep every stride-th row and column")] = 1,
    model: Annotated[str | None, typer.Option(help="the model: NAME or NAME:VERSION (default: the service's)")] = None,
    fx: Annotated[float | None, typer.Option(help="the photos' focal length, pixels (EXIF, else the model's)")] = None,
    concurrency: Annotated[int, typer.Option(min=1, help="requests in flight at once")] = 1,
    overwrite: Annotated[
        bool, typer.Option(help="redo outputs that exist (default: skip them, resuming a batch)")
    ] = False,
) -> None:
    """Send images to a running service and save depth PNGs and/or PLY point clouds."""
    from cli.service import service_url
    from clients.photos import ClientOptions, OutputTally, run

    kinds = [k for k, on in (("depth", depth), ("pointcloud", pointcloud)) if on]
    if not kinds:
        raise typer.BadParameter("nothing to do: enable --depth and/or --pointcloud")
    params = {key: value for key, value in (("model", model), ("fx", fx)) if value is not None}
    options = ClientOptions(
        url=url or service_url(),
        timeout_s=timeout,
        retries=retries,
        concurrency=concurrency,
        overwrite=overwrite,
        params=params,
        cloud_params={"stride": stride},
    )
    tally = OutputTally()
    for image, outcome in run(source, kinds, out, options):
        tally.add(outcome)
        typer.echo(f"{image}: {outcome}", err=outcome.startswith("error"))
    typer.echo(tally.summary(), err=bool(tally.failed))
    if tally.failed:
        raise typer.Exit(1)


def parse_colour_camera(text: str, option: str = "--colour-camera") -> ColourCamera:
    """A colour camera option as YAML flow, the way a data source's ``colour_camera`` is written."""
    from contract.geometry import ColourCamera

    try:
        return ColourCamera.from_flow(text)
    except ValueError as e:
        raise typer.BadParameter(f"{option} {text!r}: {e}") from e


def run_app(commands: typer.Typer) -> None:
    """Run a command line; mistakes a user can fix print one line and exit 1, a bug keeps its traceback.

    A user's mistake is a ``UserError`` (a bad config, recording, card or option), a ``ValidationError``
    (options or files that do not fit their schema) or an ``OSError`` (a path that is missing or
    unreadable); anything else propagates, so its traceback says where the bug is.
    """
    from pydantic import ValidationError

    from contract.errors import UserError

    try:
        commands()
    except (OSError, UserError, ValidationError) as e:
        typer.echo(f"error: {e}", err=True)
        raise SystemExit(1) from None


def main() -> None:
    run_app(app)
