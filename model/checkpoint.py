"""Checkpoints: everything a run needs to continue exactly, written atomically.

Loading a generator also takes a published version folder, whose TorchScript
weights and card stand in for a checkpoint that may no longer exist.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from model.card import TORCHSCRIPT_FILE, load_card, verify_files
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


def load_generator(
    path: Path, run_as: dict[str, Any] | None = None
) -> tuple[GlobalGenerator, RunConfig, dict[str, Any]]:
    """The generator of a checkpoint or a published version, in eval mode, with its run config.

    ``run_as`` changes its ``INFERENCE_ONLY`` settings (``GeneratorConfig.run_as``), so
    trained weights can be scored and exported with another inference path. A run
    with ``optim.ema`` is judged by its averaged weights, so those are the ones
    loaded; the raw weights beside them only serve ``--resume``.

    A published version folder (checked against its card) gives the weights in its
    TorchScript file and a state rebuilt from its card, so a version whose training
    checkpoint is gone can still be run another way and published again.
    """
    path = Path(path)
    state = _published_state(path) if path.is_dir() else load_checkpoint(path)
    config = RunConfig.model_validate(state["config"])
    config.generator = state.get("generator_config", config.generator).run_as(run_as or {})
    generator = GlobalGenerator(config.generator)
    generator.load_state_dict(state.get("generator_ema", state["generator"]))  # strict: a config mismatch fails loudly
    return generator.eval(), config, state


def _published_state(version_dir: Path) -> dict[str, Any]:
    """What a checkpoint holds that a published version can give back: its weights and its training."""
    card = load_card(version_dir)
    verify_files(version_dir, card)
    module = torch.jit.load(str(version_dir / TORCHSCRIPT_FILE), map_location="cpu")
    return {
        "generator": module.state_dict(),
        "generator_config": card.generator,  # as exported, which may differ from training's in INFERENCE_ONLY
        "config": card.training.config,
        "step": card.training.steps,
        "train_seconds": card.training.duration_s,
        "hardware": card.training.hardware,
        "published": f"{card.name} {card.version}",
    }


def load_ensemble(
    paths: list[Path], run_as: dict[str, Any] | None = None
) -> tuple[GlobalGenerator | GeneratorEnsemble, RunConfig, list[dict[str, Any]]]:
    """One checkpoint's generator, or several averaged as one (``GeneratorEnsemble``).

    The members must agree on everything that shapes their output (the generator and
    the depth encoding); the returned config is the first member's, the states are all.
    """
    if not paths:
        raise ValueError("no checkpoint given")
    loaded = [load_generator(p, run_as) for p in paths]
    generators, configs, states = zip(*loaded, strict=True)
    if len(loaded) == 1:
        return generators[0], configs[0], list(states)
    for path, config in zip(paths[1:], configs[1:], strict=True):
        for section in ("generator", "depth"):
            if getattr(config, section) != getattr(configs[0], section):
                raise ValueError(f"{path}: its {section} config differs from {paths[0]}'s; cannot average them")
    return GeneratorEnsemble(list(generators)).eval(), configs[0], list(states)
