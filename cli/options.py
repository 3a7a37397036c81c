"""Options and parsers that several ``rgb2cloud`` (and ``rgb2cloud-lab``) commands share."""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

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
#: A recording's camera where its own files lack or mistake it (folders, tum, csv and, in fit, bags and captures).
Fx = Annotated[float | None, typer.Option(help="focal length x in pixels (overrides the recording's own)")]
Fy = Annotated[float | None, typer.Option(help="focal length y in pixels")]
Cx = Annotated[float | None, typer.Option(help="principal point x in pixels")]
Cy = Annotated[float | None, typer.Option(help="principal point y in pixels")]
DepthScale = Annotated[float | None, typer.Option(help="raw depth units per metre (1000: millimetres)")]
MinDepth = Annotated[float, typer.Option(help="valid ground truth from (m)")]
MaxDepth = Annotated[float, typer.Option(help="valid ground truth up to (m)")]
REGISTRY_HELP = "registry to publish into (default: $RGB2CLOUD_REGISTRY, else ~/.local/share/rgb2cloud/models)"


def parse_size(option: str, text: str) -> tuple[int, int]:
    """A ``WxH`` size in pixels (``320x240``, ``320X240``), or a one-line error."""
    found = re.fullmatch(r"(\d+)x(\d+)", text.strip().lower(), re.ASCII)
    if found is None or 0 in (size := (int(found[1]), int(found[2]))):
        raise typer.BadParameter(f"{option} {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 320x240")
    return size


def parse_colour_camera(text: str, option: str = "--colour-camera") -> ColourCamera:
    """A colour camera option as YAML flow, the way a data source's ``colour_camera`` is written."""
    from contract.geometry import ColourCamera

    try:
        return ColourCamera.from_flow(text)
    except ValueError as e:
        raise typer.BadParameter(f"{option} {text!r}: {e}") from e
