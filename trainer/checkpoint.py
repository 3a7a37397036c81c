"""Checkpoints: everything a run needs to continue exactly, written atomically.

On disk a checkpoint is a dict of tensors and plain values (``torch.load`` with
``weights_only=True`` reads nothing else); in code it is a ``Checkpoint``. A generator
to run or start from is ``TrainedWeights``, which a published version folder gives too:
its weights (``generator.safetensors``; the TorchScript file of a version older than that) and
its card stand in for a checkpoint that may no longer exist.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from contract.card import ONNX_FILE, TORCHSCRIPT_FILE, WEIGHTS_FILE, load_card, verify_files
from contract.errors import UserError
from contract.geometry import Intrinsics
from contract.spec import GeneratorSpec, InferenceSettings
from trainer.config import RunConfig, migrate_config
from trainer.inference import InferenceGraph
from trainer.networks import build_generator

StateDict = dict[str, Any]


@dataclass(frozen=True)
class HardwareStretch:
    """Steps from ``first_step`` on ran on ``hardware`` (until the next stretch, or the run's end)."""

    first_step: int
    hardware: str


def hardware_history(stretches: list[HardwareStretch], step: int) -> str:
    """The card's hardware line: one machine, or each stretch of steps when a resume changed it."""
    if len(stretches) == 1:
        return stretches[0].hardware
    ends = [s.first_step for s in stretches[1:]] + [step]
    return "; ".join(f"steps {s.first_step}-{end}: {s.hardware}" for s, end in zip(stretches, ends, strict=True))


@dataclass
class Best:
    """The best validation so far: its score (lower is better), step and metrics."""

    score: float
    step: int
    metrics: dict[str, float]


@dataclass
class Checkpoint:
    """A run's whole state after ``step`` steps: networks, optimisers, scaler, clock and history."""

    generator: StateDict
    discriminator: StateDict
    opt_g: StateDict
    opt_d: StateDict
    scaler: StateDict
    step: int
    best: Best | None
    train_seconds: float
    stretches: list[HardwareStretch]
    config: dict[str, Any]
    #: The camera the generator is trained at (``trainer.train.model_camera``), kept so that evaluating or
    #: exporting the checkpoint never reopens its training data to learn it.
    camera: Intrinsics | None

    @property
    def hardware(self) -> str:
        return hardware_history(self.stretches, self.step)

    def to_dict(self) -> dict[str, Any]:
        state = {key: getattr(self, key) for key in ("generator", "discriminator", "opt_g", "opt_d", "scaler")}
        return {
            **state,
            "step": self.step,
            "best": None if self.best is None else asdict(self.best),
            "train_seconds": self.train_seconds,
            "hardware": self.hardware,
            "hardware_segments": [[s.first_step, s.hardware] for s in self.stretches],
            "config": self.config,
            "camera": None if self.camera is None else asdict(self.camera),
        }

    @classmethod
    def from_dict(cls, state: dict[str, Any]) -> Checkpoint:
        """A checkpoint as saved; one saved before stretches were kept ran on its one ``hardware``."""
        segments = state.get("hardware_segments") or [[0, state["hardware"]]]
        return cls(
            **{key: state[key] for key in ("generator", "discriminator", "opt_g", "opt_d", "scaler", "step")},
            best=None if state["best"] is None else Best(**state["best"]),
            train_seconds=state["train_seconds"],
            stretches=[HardwareStretch(first, hardware) for first, hardware in segments],
            config=state["config"],
            camera=None if state.get("camera") is None else Intrinsics(**state["camera"]),
        )


@dataclass
class TrainedWeights:
    """A generator's weights with what made them: from a checkpoint, or a published version."""

    generator: StateDict
    config: RunConfig
    step: int
    train_seconds: float
    hardware: str
    #: The camera the generator was trained at: a checkpoint's own, or a version's card camera.
    camera: Intrinsics
    #: ``NAME VERSION`` when read from a published version folder.
    published: str | None = None
    #: The settings it runs with: a published version's as exported, else its run config's.
    inference: InferenceSettings = field(default_factory=InferenceSettings)


def save_checkpoint(path: Path, checkpoint: Checkpoint) -> None:
    """Write to a temporary name and rename, so a crash never leaves half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(checkpoint.to_dict(), tmp)
    os.replace(tmp, path)


def load_checkpoint(path: Path) -> Checkpoint:
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no checkpoint")
    return Checkpoint.from_dict(torch.load(path, map_location="cpu", weights_only=True))


def load_weights(path: Path) -> TrainedWeights:
    """A checkpoint's generator, or a published version's, with its run config migrated."""
    path = Path(path)
    if path.is_dir():
        return _published_weights(path)
    checkpoint = load_checkpoint(path)
    if checkpoint.camera is None:
        raise UserError(
            f"{path}: this checkpoint does not say which camera it was trained at (it was saved before "
            "checkpoints did); continue its training with --resume, and its next checkpoint will"
        )
    config = RunConfig.model_validate(migrate_config(checkpoint.config))
    return TrainedWeights(
        checkpoint.generator,
        config,
        checkpoint.step,
        checkpoint.train_seconds,
        checkpoint.hardware,
        checkpoint.camera,
        inference=config.inference,
    )


def load_graph(path: Path, inference: dict[str, Any] | None = None) -> tuple[InferenceGraph, TrainedWeights]:
    """The inference graph of a checkpoint or a published version, in eval mode, with what made it.

    ``inference`` changes some of its inference settings (``contract.spec.InferenceSettings``),
    so trained weights can be scored and exported with another inference path; the
    returned weights' config and ``inference`` carry the settings in use.

    A published version folder (checked against its card) gives the weights in its
    ``generator.safetensors`` (its TorchScript file, before that) and a config rebuilt from
    its card, so a version whose training checkpoint is gone can still be run another way and
    published again.
    """
    weights = load_weights(path)
    weights.inference = weights.inference.updated(inference or {})
    weights.config.inference = weights.inference
    generator = build_generator(weights.config.generator)
    generator.load_state_dict(weights.generator)  # strict: a spec that does not fit the weights fails loudly
    return InferenceGraph(generator, weights.inference).eval(), weights


def load_generator_weights(path: Path, spec: GeneratorSpec) -> StateDict:
    """The generator weights of a checkpoint or published version, to start a run from.

    Only the generator carries over: a new place needs a discriminator that judges it
    afresh. The spec must be the run's own, so the weights fit the network, except for
    ``upsampler``: a run that swaps it keeps every other layer (``start_weights``).
    """
    weights = load_weights(path)
    theirs = weights.config.generator
    if theirs.model_copy(update={"upsampler": spec.upsampler}) != spec:
        raise UserError(f"{path}: its generator {theirs.model_dump()} is not this run's {spec.model_dump()}")
    return weights.generator


def _published_weights(version_dir: Path) -> TrainedWeights:
    """What a checkpoint holds that a published version can give back: its weights and its training."""
    card = load_card(version_dir)
    verify_files(version_dir, card)
    if WEIGHTS_FILE in card.files:
        from safetensors.torch import load_file

        generator = load_file(str(version_dir / WEIGHTS_FILE))
    else:
        generator = _torchscript_weights(version_dir)
    config = {**card.training.config, "generator": card.generator.model_dump()}
    return TrainedWeights(
        generator,
        RunConfig.model_validate(migrate_config(config)),
        card.training.steps,
        card.training.duration_s,
        card.training.hardware,
        card.camera,
        published=f"{card.name} {card.version}",
        inference=card.inference,  # as exported, which may differ from the training config's
    )


def _torchscript_weights(version_dir: Path) -> StateDict:
    """The generator's weights from a version published before ``WEIGHTS_FILE`` (0.8.x, 0.9.0): its TorchScript,
    which loads only under a torch that has every operator the writing torch recorded in it."""
    try:
        state = torch.jit.load(str(version_dir / TORCHSCRIPT_FILE), map_location="cpu").state_dict()
    except RuntimeError as e:
        writer = _writing_torch(version_dir)
        cause = str(e).strip().splitlines()[0][:160] if str(e).strip() else type(e).__name__
        install = f"install torch=={writer.split('+')[0]}" if writer else "install the torch that exported it"
        by = f"torch {writer}" if writer else "another torch"
        raise UserError(
            f"{version_dir}: its weights are TorchScript written by {by}, which torch "
            f"{torch.__version__} cannot load ({cause}); {install} to start from it, or start from a version "
            f"that has {WEIGHTS_FILE}"
        ) from None
    # Export writes the inference graph, whose generator's keys start "generator."; a schema-1
    # card's file is the bare generator, whose keys are the generator's own.
    return {key.removeprefix("generator."): tensor for key, tensor in state.items()}


def _writing_torch(version_dir: Path) -> str | None:
    """The torch that exported a version: its ONNX graph's producer version, if it says."""
    import onnx

    try:
        return onnx.load(str(version_dir / ONNX_FILE), load_external_data=False).producer_version or None
    except Exception:  # an unreadable graph says nothing about its writer; the weights' error is the one to tell
        return None


def start_weights(generator: torch.nn.Module, path: Path, spec: GeneratorSpec) -> StateDict:
    """``generator``'s state with every layer that ``path`` has in the same shape taken from it.

    With the same spec that is every layer; with another upsampler, the upsampling layers keep
    their fresh initialisation (their keys differ), and the encoder, residual blocks and output
    layer carry over.
    """
    own = generator.state_dict()
    given = load_generator_weights(path, spec)
    kept = {key: tensor for key, tensor in given.items() if key in own and own[key].shape == tensor.shape}
    return {**own, **kept}
