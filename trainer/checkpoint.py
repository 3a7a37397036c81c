"""Checkpoints: everything a run needs to continue exactly, written atomically.

Loading a generator also takes a published version folder, whose TorchScript
weights and card stand in for a checkpoint that may no longer exist.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from contract.card import TORCHSCRIPT_FILE, load_card, verify_files
from contract.spec import GeneratorSpec
from trainer.config import RunConfig, migrate_config
from trainer.inference import InferenceGraph
from trainer.networks import GlobalGenerator


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


def load_state(path: Path) -> tuple[dict[str, Any], RunConfig]:
    """A checkpoint's state, or a published version's stand-in for one, with its run config migrated."""
    path = Path(path)
    state = _published_state(path) if path.is_dir() else load_checkpoint(path)
    return state, RunConfig.model_validate(migrate_config(state["config"]))


def load_graph(path: Path, inference: dict[str, Any] | None = None) -> tuple[InferenceGraph, RunConfig, dict[str, Any]]:
    """The inference graph of a checkpoint or a published version, in eval mode, with its run config.

    ``inference`` changes some of its inference settings (``contract.spec.InferenceSettings``),
    so trained weights can be scored and exported with another inference path; the
    returned config carries the settings in use.

    A published version folder (checked against its card) gives the weights in its
    TorchScript file and a state rebuilt from its card, so a version whose training
    checkpoint is gone can still be run another way and published again.
    """
    state, config = load_state(path)
    config.inference = state.get("inference", config.inference).updated(inference or {})
    generator = GlobalGenerator(config.generator)
    generator.load_state_dict(state["generator"])  # strict: a spec that does not fit the weights fails loudly
    return InferenceGraph(generator, config.inference).eval(), config, state


def load_generator_weights(path: Path, spec: GeneratorSpec) -> dict[str, Any]:
    """The generator weights of a checkpoint or published version, to start a run from.

    Only the generator carries over: a new place needs a discriminator that judges it
    afresh. The spec must be the run's own, so the weights fit the network.
    """
    state, config = load_state(path)
    theirs = config.generator
    if theirs != spec:
        raise ValueError(f"{path}: its generator {theirs.model_dump()} is not this run's {spec.model_dump()}")
    return state["generator"]


def _published_state(version_dir: Path) -> dict[str, Any]:
    """What a checkpoint holds that a published version can give back: its weights and its training."""
    card = load_card(version_dir)
    verify_files(version_dir, card)
    weights = torch.jit.load(str(version_dir / TORCHSCRIPT_FILE), map_location="cpu").state_dict()
    # Export writes the inference graph, whose generator's keys start "generator."; a schema-1
    # card's file is the bare generator, whose keys are the generator's own.
    generator = {key.removeprefix("generator."): tensor for key, tensor in weights.items()}
    return {
        "generator": generator,
        "inference": card.inference,  # as exported, which may differ from the training config's
        "config": {**card.training.config, "generator": card.generator.model_dump()},
        "step": card.training.steps,
        "train_seconds": card.training.duration_s,
        "hardware": card.training.hardware,
        "published": f"{card.name} {card.version}",
    }
