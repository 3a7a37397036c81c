"""``rgb2cloud train`` and ``export``: a model from a run config, and a published version from its weights."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli.options import REGISTRY_HELP, Inference, PrecisionOption, checked


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
