"""``rgb2cloud fit``: a model of the user's space from one recording, scored on views it held out, and published."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli.options import REGISTRY_HELP, Cx, Cy, DepthScale, Fx, Fy, PrecisionOption, checked, parse_size
from recordings.frames import DEFAULT_MAX_FRAMES  # numpy and PIL only: the serving install has them

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
Pixels = Annotated[
    str,
    typer.Option(
        help="the size the model learns and serves the recording's camera at, WxH; its area counts, the recording "
        "keeps its shape: fewer pixels run faster and see less detail",
    ),
]
MaxFrames = Annotated[
    int,
    typer.Option(
        help="keep at most this many pairs, evenly spread, and write only those (0: all); "
        "the default is about what a 30-minute CPU fit can use",
        min=0,
    ),
]
Steps = Annotated[
    int | None,
    typer.Option(help="train exactly this many steps, however long they take (default: the budget's)", min=1),
]


def fit(
    data: Annotated[Path, typer.Argument(help="the recording: a folder (color/ + depth/, TUM, 7-Scenes) or a file")],
    name: Annotated[str, typer.Option(help="the model's name in the registry")],
    licence: Annotated[str, typer.Option(help="the terms the recording may be used under (required)")],
    budget: Annotated[float, typer.Option(help="minutes, wall clock, for the whole command", min=1)] = 30.0,
    from_: FitFrom = None,
    registry: Annotated[Path | None, typer.Option(help=REGISTRY_HELP)] = None,
    format: FitFormat = None,
    fx: Fx = None,
    fy: Fy = None,
    cx: Cx = None,
    cy: Cy = None,
    depth_scale: DepthScale = None,
    holdout: Holdout = None,
    gap: Gap = None,
    color_topic: Annotated[str | None, typer.Option(help="a bag's colour image topic (default: found)")] = None,
    depth_topic: DepthTopic = None,
    max_gap_ms: MaxGapMs = None,
    min_confidence: MinConfidence = None,
    every: Annotated[int, typer.Option(help="keep every Nth pair of a long recording", min=1)] = 1,
    max_frames: MaxFrames = DEFAULT_MAX_FRAMES,
    register: Register = "auto",
    out: Annotated[Path | None, typer.Option(help="run folder (default runs/fit/NAME)")] = None,
    resume: Annotated[bool, typer.Option(help="continue an interrupted fit from its last checkpoint")] = False,
    set_: RecipeChanges = [],  # noqa: B006
    steps: Steps = None,
    precision: PrecisionOption = "fp32",
    pixels: Pixels = "640x480",
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
        pixels=parse_size("--pixels", pixels),
    )
    try:
        run(options, typer.echo)
    except KeyboardInterrupt:
        typer.echo(interrupted_hint(options.run_dir), err=True)
        raise typer.Exit(130) from None
