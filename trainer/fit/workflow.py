"""``rgb2cloud fit`` from start to end: read, check, split, plan, train, score, publish.

Everything a fit decides is written to its run folder before training starts
(``fit.json``, and the split as CSV manifests), so ``--resume`` after Ctrl-C or a crash
continues the same plan from the last checkpoint instead of starting over.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from contract.card import IMAGENET_START, DataRef, FitRecord, ModelCard, load_card, next_version
from contract.errors import UserError
from contract.geometry import ColourCamera
from contract.registries import Registries
from contract.runtime import Precision
from contract.spec import GeneratorSpec
from recordings.formats import ReadOptions, Recording, open_recording
from recordings.frames import TRAINED_SIZE, read_pair
from recordings.manifest import ManifestReader, write_manifest
from trainer.config import DataSource, RunConfig, apply_overrides
from trainer.fit.budget import Pacer, Plan, Workload, measure_seconds, plan_training, resumed_deadline
from trainer.fit.inspect import inspect_recording, readable
from trainer.fit.progress import Progress, RunLock
from trainer.fit.scoring import score_holdout
from trainer.fit.split import MIN_PAIRS, Split, split_recording
from trainer.fit.start import resolve_start, start_recipe
from trainer.fit.state import FitState, new_fit_id, published_by, save_state
from trainer.torch_support import require_supported_torch
from trainer.train import model_camera

#: The masked L1's weight in a fit whose start was trained without one (the bundled recipe's).
FIT_L1 = 100.0
#: Adam's settings in a fit (the decay is planned from the budget).
FIT_ADAM = {"lr": 0.0005, "beta1": 0.9}


@dataclass
class FitOptions:
    data: Path
    name: str
    licence: str
    #: Where the service is reached (the CLI reads the service's own host and port settings).
    service_url: str
    #: The registries: where fit publishes (the user's, ``RGB2CLOUD_REGISTRY``, or ``--registry``), and the bundled
    #: one whose base model a fit starts from and whose names it may not take.
    registry: Path
    bundled: Path
    budget_min: float = 30.0
    #: A published version folder, a model in the registries (``NAME`` for its newest version, or ``NAME:VERSION``),
    #: ``IMAGENET_START``, or None for ``BASE_MODEL``'s newest bundled version.
    start_from: str | None = None
    format: str | None = None
    read: ReadOptions = field(default_factory=ReadOptions)
    #: ``section.key=value`` changes to the start's recipe (``train``'s override syntax).
    overrides: list[str] = field(default_factory=list)
    #: Train exactly this many steps instead of what the budget allows.
    steps: int | None = None
    #: "int8": publish an int8 graph beside the fp32 ones (``export --precision``).
    precision: Precision = "fp32"
    holdout: str | None = None
    gap_frames: int | None = None
    registration: str = "auto"
    out: Path | None = None
    resume: bool = False
    #: The size whose area the recording's camera is scaled to (never up) for the model to learn and serve:
    #: the card's camera, which the service resamples every photo to. Fewer pixels run faster and see less
    #: detail (docs/benchmarks.md, "A model for live").
    pixels: tuple[int, int] = TRAINED_SIZE

    @property
    def run_dir(self) -> Path:
        return self.out or Path("runs") / "fit" / self.name


def fit(options: FitOptions, echo: Callable[[str], None] = print) -> Path:
    """Fit a model of the recorded place; returns the published version folder."""
    require_supported_torch()  # before minutes of work that an unsupported torch would fail deep inside
    started = time.monotonic()
    run = options.run_dir
    with RunLock(run):
        return _fit_locked(options, started, echo)


def _fit_locked(options: FitOptions, started: float, echo: Callable[[str], None]) -> Path:
    """``fit`` while it alone writes into its run folder."""
    run = options.run_dir
    state_file = run / "fit.json"
    if options.resume and not state_file.is_file():
        raise UserError(f"{run}: nothing to resume (no fit.json); run without --resume")
    if not options.resume and state_file.exists():
        raise UserError(f"{run}: a fit is already there; add --resume to continue it, or pass --out elsewhere")
    if not options.licence.strip():
        raise UserError("--licence is required: the terms under which the recording may be used")
    Registries(options.registry, options.bundled).check_new_name(options.name, options.registry)
    state = FitState.model_validate_json(state_file.read_text()) if options.resume else None
    if state is not None and not state.published and (found := published_by(state, options.registry, options.name)):
        state.published = str(found)  # Ctrl-C came after publishing, before fit.json said so
        save_state(state_file, state)
    if state is not None and state.published:
        raise UserError(
            f"{run}: this fit finished and published {state.published}; there is nothing to resume "
            "(for another model, run fit with another --name or --out)"
        )
    progress = Progress(options.budget_min * 60, started)
    try:
        if state is not None:
            for line in state.report:
                progress.say(line)
        else:
            state = _prepare(options, run, progress, started)
            save_state(state_file, state)
        target = _train_score_publish(options, state, progress)
        state.published = str(target)
        save_state(state_file, state)
        progress.finish()
    finally:
        progress.close()
    for line in _serve_lines(options.registry, options.name, target.name, options.service_url):
        echo(line)
    return target


def _prepare(options: FitOptions, run: Path, progress: Progress, started: float) -> FitState:
    """Everything decided before training: the data checked and split, the config, the plan."""
    recording = open_recording(options.data, options.format, options.read, run)
    progress.phase("inspecting")
    recording = readable(recording)
    found = [f"{recording.root} ({recording.format})", *recording.notes]
    for line in found:  # what the reader found, before anything can refuse the recording
        progress.say(line)
    if len(recording.pairs) < MIN_PAIRS:
        name, why = recording.skipped[0] if recording.skipped else ("", "")
        cause = f"; {len(recording.skipped)} skipped, e.g. {name}: {why}" if why else " (record a little longer)"
        raise UserError(f"{recording.root}: {len(recording.pairs)} usable pairs, fit needs at least {MIN_PAIRS}{cause}")
    inspection = inspect_recording(recording, registration=options.registration)
    split = split_recording(recording.pairs, options.holdout, options.gap_frames)
    checked = [*inspection.lines(), split.line()]
    for line in checked:
        progress.say(line)
    report = found + checked
    start = resolve_start(options.start_from, Registries(options.registry, options.bundled))
    config = _run_config(options, recording, split, inspection.colour_camera, start, run)
    seen = model_camera(config)
    camera = f"camera: the model sees every photo at {seen.width}x{seen.height}, fx {seen.fx:.1f} (--pixels)"
    progress.say(camera)
    report += [camera, *_render_views(config, progress)]
    progress.phase("measuring")
    step_s, predict_s = measure_seconds(config)
    radius = config.inference.median_radius
    taps = (2 * radius + 1) ** 2 if radius else 0
    int8 = options.precision == "int8"
    work = Workload(len(split.selection), len(split.holdout), predict_s, start is not None, taps, int8)
    plan = plan_training(options.budget_min * 60, time.monotonic() - started, step_s, work, options.steps)
    progress.say(plan.line())
    config.train = config.train.model_copy(
        update={"steps": plan.steps, "val_every": plan.val_every, "checkpoint_every": plan.checkpoint_every}
    )
    config.optim = config.optim.model_copy(
        update={"decay_start": plan.decay_start, "decay_steps": plan.steps - plan.decay_start}
    )
    return FitState(
        fit_id=new_fit_id(),
        report=[*report, plan.line()],
        data=str(options.data),
        format=recording.format,
        licence=options.licence,
        start_from=str(start) if start else IMAGENET_START,
        split=split.summary(recording.pairs),
        colour_camera=inspection.colour_camera,
        plan=plan,
        config=config,
    )


def _render_views(config: RunConfig, progress: Progress) -> list[str]:
    """The bank of rendered views (``data.views``), made before the plan so its minutes come out of the budget."""
    from trainer.data.loader import training_frames, training_views

    if config.data.views.share == 0:
        return []
    progress.phase("rendering views")
    began = time.monotonic()
    frames = training_frames(config)
    bank = training_views(config, frames)
    if bank is None:
        raise RuntimeError("data.views.share is above 0 but no bank of views was made")
    line = (
        f"rendered views: {len(bank.reader)}, {bank.per_frame} of each of the {len(frames)} train frames, in "
        f"{time.monotonic() - began:.0f} s ({bank.render_ms:.0f} ms a view); {config.data.views.share:.0%} of "
        "each batch"
    )
    progress.say(line)
    return [line]


def _run_config(
    options: FitOptions,
    recording: Recording,
    split: Split,
    colour: ColourCamera | None,
    start: Path | None,
    run: Path,
) -> RunConfig:
    """The starting model's recipe on this recording's split, at the scale the service will see it."""
    tree = start_recipe(start, options.bundled)
    pairs = recording.pairs
    manifests = {
        part: write_manifest(run / f"{part}.csv", [pairs[i] for i in getattr(split, part)])
        for part in ("train", "selection", "holdout")
    }
    source = {"format": "csv", "licence": options.licence, "colour_camera": colour.model_dump() if colour else None}
    height, width = read_pair(pairs[0]).depth.shape
    area = options.pixels[0] * options.pixels[1]
    scale = min(1.0, math.sqrt(area / (height * width)))  # what the service shrinks this camera's photos to
    # The crop is a multiple of the generator's stride: of the generator the run trains, --set included.
    spec = GeneratorSpec.model_validate(apply_overrides(tree, options.overrides)["generator"])
    work, multiple = spec.work_scale, spec.core_multiple
    size = [int(height * scale / work) // multiple * multiple, int(width * scale / work) // multiple * multiple]
    if min(size) < multiple:
        asked = "x".join(map(str, options.pixels))
        raise UserError(
            f"the model would see this {width}x{height} recording at {round(width * scale)}x{round(height * scale)} "
            f"(--pixels {asked}), and its generator needs at least {multiple * work} pixels a side"
        )
    tree["data"] = {
        "train": [{**source, "root": str(manifests["train"])}],
        "val": [{**source, "root": str(manifests["selection"])}],
        "val_scale": scale,
        # Whole frames only: a site model serves its own camera's photos, and views narrower than the frame
        # cost fits from 0.9.0 0.036 δ1 on aims-lab (docs/quality.md), as crops alone did (docs/research.md).
        "transform": {
            **tree["data"]["transform"],
            "size": size,
            "scale": [scale / work, 1.1 * scale / work],
            "extent": [1.0, 1.0],
            "whole_share": 0.0,
        },
        "eval_min_m": tree["data"]["eval_min_m"],
        "eval_max_m": tree["data"]["eval_max_m"],
    }
    # A fit learns from the masked L1 alone: with no discriminator to run, a budget trains 2.2x the steps,
    # and a 10-minute fit gained 0.026 δ1 on aims-lab with mosd-tabletop level (docs/research.md). The
    # discriminator would start from scratch on a few hundred frames anyway: a published version has none.
    tree["loss"] = {
        **tree["loss"],
        "gan": 0.0,
        "feature_matching": 0.0,
        # SILog in its place where asked for (``loss.silog``), else the masked L1.
        "l1_depth": tree["loss"].get("l1_depth") or (0.0 if tree["loss"].get("silog") else FIT_L1),
    }
    # Adam as for any regression: pix2pix's lr 2e-4 and beta1 0.5 keep an adversarial game stable, and with
    # none to keep, 2.5x the rate with beta1 0.9 gained 0.013 δ1 on aims-lab and 0.009 on mosd-tabletop at
    # the same steps (docs/research.md).
    tree["optim"] = {**tree["optim"], **FIT_ADAM}
    tree["train"] = {
        "out_dir": str(run / "train"),
        "steps": 1,
        "batch_size": 4,
        "num_workers": 1,
        "seed": 0,
        "device": "auto",
        "amp": True,
        "threads": os.cpu_count(),
        "log_every": 10,
        # The last checkpoint, not the best on the selection frames: 14 frames of aims-lab at four validations chose
        # step 147 of 573 by a REL 0.009 lower, held-out δ1 0.746 against the last's 0.816 (docs/research.md, 7).
        # The selection frames still draw the run's validation curves and samples.
        "select_metric": None,
        "start_from": str(start) if start else None,
    }
    return RunConfig.model_validate(apply_overrides(tree, options.overrides))


def _train_score_publish(options: FitOptions, state: FitState, progress: Progress) -> Path:
    from trainer.export import export_and_publish
    from trainer.train import train

    config, plan = state.config, state.plan
    progress.phase("training")
    deadline = None if plan.fixed else progress.started + plan.deadline_s
    last = Path(config.train.out_dir) / "checkpoints" / "last.pt"
    resume = options.resume and last.is_file()
    if options.resume:
        if not plan.fixed:  # a fresh stretch of the budget for the steps left
            deadline = resumed_deadline(plan, _checkpoint_step(last) if resume else 0, time.monotonic())
        if resume:
            progress.say(f"resuming at step {_checkpoint_step(last)} of {plan.steps}")
        else:
            progress.say(f"resuming before the first checkpoint: training all {plan.steps} steps from the start")
    pacer = None
    if deadline is not None:

        def revised(new_plan: Plan, new_config: RunConfig, line: str) -> None:
            progress.say(line)
            state.plan, state.config = new_plan, new_config
            state.report.append(line)
            save_state(options.run_dir / "fit.json", state)  # --resume continues the corrected plan

        pacer = Pacer(plan, config, deadline, revised)
    summary = train(config, resume=resume, report=progress.tick, deadline=deadline, revise=pacer)
    progress.say(f"trained {summary.steps} steps in {summary.train_seconds / 60:.1f} min")

    progress.phase("scoring")
    checkpoints = Path(config.train.out_dir) / "checkpoints"
    checkpoint = checkpoints / "best.pt" if (checkpoints / "best.pt").is_file() else checkpoints / "last.pt"
    holdout = DataSource(format="csv", root=options.run_dir / "holdout.csv")
    table, metrics, warning = score_holdout(checkpoint, state.start, config, holdout, state.colour_camera)
    progress.say(table)
    if warning:
        progress.say(warning)

    progress.phase("publishing")
    version = next_version(options.registry, options.name)
    start = load_card(state.start) if state.start else None
    record = FitRecord(
        fit_id=state.fit_id,
        data=state.data,
        start_from=state.start_from,
        start_model=f"{start.name} {start.version}" if start else None,
        budget_min=options.budget_min,
        split=state.split,
        registered_with=state.colour_camera,
    )
    frames = sum(part["frames"] for part in state.split.values())
    data = [DataRef(name=Path(state.data).name, format=state.format, frames=f"{frames} pairs", licence=state.licence)]
    data += lineage(start) if start else []
    parity_image = ManifestReader(holdout.root).pairs[0].rgb
    target = export_and_publish(
        checkpoint,
        options.registry,
        options.name,
        version,
        metrics,
        parity_image,
        data=data,
        fit=record,
        precision=options.precision,
    )
    progress.say(f"published {target}")
    progress.say(f"run folder (config, checkpoints, split manifests): {options.run_dir}")
    return target


def lineage(start: ModelCard) -> list[DataRef]:
    """Every dataset behind a starting model, marked with the model it came through: its weights carry them all,
    and with them their licences (a fit from the kitchen model is bound by 7-Scenes' non-commercial terms)."""
    via = f"{start.name} {start.version}"
    return [ref.model_copy(update={"via": ref.via or via}) for ref in start.training.data]


def _checkpoint_step(path: Path) -> int:
    from trainer.checkpoint import load_checkpoint

    return load_checkpoint(path).step


def _serve_lines(registry: Path, name: str, version: str, url: str) -> list[str]:
    return [
        "",
        f"A service whose RGB2CLOUD_REGISTRY is {registry} serves it now, without a restart:",
        f'  curl -sS -F image=@photo.jpg "{url}/depth?model={name}:{version}" -o depth.png',
        f'  curl -sS -F image=@photo.jpg "{url}/pointcloud?model={name}:{version}" -o cloud.ply',
        "Or start one with it as the default model:",
        f"  RGB2CLOUD_REGISTRY={registry} RGB2CLOUD_MODEL={name}:{version} make serve",
    ]
