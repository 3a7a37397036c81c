"""``rgb2cloud client``: photos on disk sent to a running service, depth PNGs and PLY clouds written beside them."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


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
