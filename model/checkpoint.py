"""Checkpoints: everything a run needs to continue exactly, written atomically."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from model.config import RunConfig
from model.networks import GeneratorEnsemble, GlobalGenerator


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Write to a temporary name and rename, so a crash never leaves half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: Path) -> dict[str, Any]:
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no checkpoint")
    return torch.load(path, map_location="cpu", weights_only=True)


def load_generator(path: Path, flip_average: bool | None = None) -> tuple[GlobalGenerator, RunConfig, dict[str, Any]]:
    """The generator of a checkpoint, in eval mode, with the run config it was built from.

    ``flip_average`` (None: as trained) changes only how the weights are run, so a
    checkpoint can be scored and exported with or without it. A run with ``optim.ema``
    is judged by its averaged weights, so those are the ones loaded; the raw weights
    beside them only serve ``--resume``.
    """
    state = load_checkpoint(path)
    config = RunConfig.model_validate(state["config"])
    if flip_average is not None:
        config.generator = config.generator.model_copy(update={"flip_average": flip_average})
    generator = GlobalGenerator(config.generator)
    generator.load_state_dict(state.get("generator_ema", state["generator"]))  # strict: a config mismatch fails loudly
    return generator.eval(), config, state


def load_ensemble(
    paths: list[Path], flip_average: bool | None = None
) -> tuple[GlobalGenerator | GeneratorEnsemble, RunConfig, list[dict[str, Any]]]:
    """One checkpoint's generator, or several averaged as one (``GeneratorEnsemble``).

    The members must agree on everything that shapes their output (the generator and
    the depth encoding); the returned config is the first member's, the states are all.
    """
    if not paths:
        raise ValueError("no checkpoint given")
    loaded = [load_generator(p, flip_average) for p in paths]
    generators, configs, states = zip(*loaded, strict=True)
    if len(loaded) == 1:
        return generators[0], configs[0], list(states)
    for path, config in zip(paths[1:], configs[1:], strict=True):
        for section in ("generator", "depth"):
            if getattr(config, section) != getattr(configs[0], section):
                raise ValueError(f"{path}: its {section} config differs from {paths[0]}'s; cannot average them")
    return GeneratorEnsemble(list(generators)).eval(), configs[0], list(states)
