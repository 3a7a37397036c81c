"""The training loop: one readable pass from config to checkpoints, alone or under torchrun.

    rgb2cloud train configs/7scenes-paper.yaml                       # one process
    torchrun --nproc_per_node 2 -m cli train configs/7scenes-paper.yaml  # DDP, same code

Each step is ``trainer.gan.gan_step``: G against the current D, then D. Every
random draw in a step is seeded from (seed, step, rank), so a resumed run repeats
an uninterrupted one bit for bit on the same device.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import yaml
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from contract.card import METRIC_KEYS
from contract.errors import UserError
from contract.geometry import Intrinsics
from trainer.checkpoint import (
    Best,
    Checkpoint,
    HardwareStretch,
    hardware_history,
    load_checkpoint,
    save_checkpoint,
    start_weights,
)
from trainer.config import RunConfig, complete_config
from trainer.data.dataset import ConcatFrames
from trainer.data.loader import training_loader
from trainer.data.sources import open_source
from trainer.devices import (
    Distributed,
    hardware_description,
    leave_process_group,
    pick_device,
    rank_digests,
    setup_distributed,
    unwrap,
)
from trainer.evaluate import Predictor, evaluate_frames
from trainer.gan import Autocast, build_networks, gan_step
from trainer.inference import EagerGenerator, InferenceGraph
from trainer.losses import GANLoss
from trainer.torch_support import require_supported_torch
from trainer.visualize import sample_grid

#: Config sections that define the networks and their targets; resume refuses to change them.
FROZEN_ON_RESUME = ("generator", "discriminator", "depth", "loss")


def step_seed(seed: int, step: int, rank: int) -> int:
    return int(np.random.SeedSequence([seed, step, rank]).generate_state(1)[0])


def _check_resumable(saved: dict, config: RunConfig) -> None:
    saved, now = complete_config(saved), config.model_dump(mode="json")
    for section in FROZEN_ON_RESUME:
        if saved[section] != now[section]:
            raise UserError(
                f"cannot resume: config section '{section}' differs from the checkpoint's "
                f"({saved[section]} vs {now[section]})"
            )


#: ``revise(step, busy_s, validating_s, validations)`` after each step, with the seconds the loop has run so far
#: less its validations (batch loading, logging and checkpoints included: every step pays for them), and the
#: validations it has run and their seconds: the run's config with its steps and schedule re-planned, or None.
Revise = Callable[[int, float, float, int], RunConfig | None]


def train(
    config: RunConfig,
    resume: bool = False,
    report: Callable[[int, int], None] | None = None,
    deadline: float | None = None,
    revise: Revise | None = None,
) -> RunSummary:
    """Run (or continue) training; returns the run summary that is also written to disk.

    ``report(step, steps)`` after each step replaces the run's own progress bar (``fit``
    draws one bar for its whole command). At ``deadline`` (``time.monotonic()``), a
    single-process run saves its checkpoint and stops early: a wall-clock budget holds
    even when the machine runs slower than it was measured. ``revise`` lets the caller
    re-plan the steps as they run (``fit``: a budget kept when steps run faster or slower
    than they were measured).
    """
    require_supported_torch()
    ddp = setup_distributed("cuda" if config.train.device != "cpu" and torch.cuda.is_available() else "cpu")
    if (deadline is not None or revise is not None) and ddp.world_size > 1:
        raise ValueError("a deadline or a re-plan changes one process; under torchrun the ranks would part ways")
    try:
        return _train(config, resume, ddp, report, deadline, revise)
    finally:
        if ddp.world_size > 1:
            leave_process_group()


def score_generator(
    generator: nn.Module, config: RunConfig, frames: ConcatFrames, camera: Intrinsics
) -> tuple[dict, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Validation: the generator run as export will run it (its inference settings, at its card's ``camera``)."""
    generator.eval()
    runner = EagerGenerator(InferenceGraph(generator, config.inference), config.generator.input_multiple)
    predict = Predictor(lambda rgb: config.depth.decode(runner.predict_raw(rgb)), camera, "validation")
    result, _, grid = evaluate_frames(
        predict, frames, min_m=config.data.eval_min_m, max_m=config.data.eval_max_m, samples=4
    )
    generator.train()
    return result, grid


@dataclass
class Run:
    """One run's networks and what changes as it goes: the step, the best validation, the clock.

    The loop in ``_train`` moves it forward; ``validate`` and ``Run.checkpoint`` read it.
    """

    config: RunConfig
    ddp: Distributed
    device: torch.device
    generator: nn.Module
    discriminator: nn.Module
    opt_g: torch.optim.Adam
    opt_d: torch.optim.Adam
    scaler: torch.amp.GradScaler
    autocast: Autocast
    step: int = 0
    best: Best | None = None
    train_seconds: float = 0.0
    stretches: list[HardwareStretch] = field(default_factory=list)
    writer: SummaryWriter | None = None
    val_frames: ConcatFrames | None = None
    #: The camera the generator is trained at (``model_camera``): validation resamples every frame to it, and
    #: each checkpoint carries it.
    camera: Intrinsics | None = None

    @property
    def out(self) -> Path:
        return Path(self.config.train.out_dir)

    @property
    def hardware(self) -> str:
        return hardware_history(self.stretches, self.step)

    def checkpoint(self) -> Checkpoint:
        return Checkpoint(
            generator=unwrap(self.generator).state_dict(),
            discriminator=unwrap(self.discriminator).state_dict(),
            opt_g=self.opt_g.state_dict(),
            opt_d=self.opt_d.state_dict(),
            scaler=self.scaler.state_dict(),
            step=self.step,
            best=self.best,
            train_seconds=self.train_seconds,
            stretches=self.stretches,
            config=self.config.model_dump(mode="json"),
            camera=self.camera,
        )

    def save(self, name: str) -> None:
        save_checkpoint(self.out / "checkpoints" / name, self.checkpoint())


@dataclass
class RunSummary:
    """What a finished run reports, and writes to ``<out_dir>/summary.json``."""

    steps: int
    train_seconds: float
    hardware: str
    best: Best | None
    #: One digest of G and D per rank: equal digests prove the ranks ended with the same weights.
    rank_weight_sha256: list[str]
    last_losses: dict[str, float]


def start_run(config: RunConfig, resume: bool, ddp: Distributed) -> Run:
    """The networks, fresh (from ``train.start_from`` if set) or as the last checkpoint left them."""
    device = pick_device(config.train.device, ddp.local_rank)
    if config.train.threads:
        torch.set_num_threads(config.train.threads)
    generator, discriminator, opt_g, opt_d = build_networks(config, device)
    autocast = Autocast.for_device(device, config.train.amp)
    scaler = torch.amp.GradScaler(device.type, enabled=autocast.scaled)
    run = Run(config, ddp, device, generator, discriminator, opt_g, opt_d, scaler, autocast)
    if resume:
        saved = load_checkpoint(run.out / "checkpoints" / "last.pt")
        _check_resumable(saved.config, config)
        generator.load_state_dict(saved.generator)
        discriminator.load_state_dict(saved.discriminator)
        opt_g.load_state_dict(saved.opt_g)
        opt_d.load_state_dict(saved.opt_d)
        scaler.load_state_dict(saved.scaler)
        run.step, run.best, run.train_seconds, run.stretches = (
            saved.step,
            saved.best,
            saved.train_seconds,
            saved.stretches,
        )
    elif config.train.start_from is not None:
        generator.load_state_dict(start_weights(generator, config.train.start_from, config.generator))
    hardware = hardware_description(device, ddp.world_size)
    if not run.stretches or run.stretches[-1].hardware != hardware:
        run.stretches.append(HardwareStretch(run.step, hardware))
    if ddp.world_size > 1:
        ids = [device.index] if device.type == "cuda" else None
        run.generator = DistributedDataParallel(generator, device_ids=ids)
        run.discriminator = DistributedDataParallel(discriminator, device_ids=ids)
    run.camera = model_camera(config)
    if config.data.val:
        run.val_frames = ConcatFrames([open_source(s) for s in config.data.val])
    if ddp.is_main:
        run.out.mkdir(parents=True, exist_ok=True)
        (run.out / "config.yaml").write_text(yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))
        run.writer = SummaryWriter(run.out / "tensorboard", purge_step=run.step)
    return run


def model_camera(config: RunConfig) -> Intrinsics:
    """The camera a run's generator was trained at: its first source's, at the run's ``val_scale``.

    Training crops and validation frames are resized by ``val_scale`` (the exported graph's
    input scale), so this is the focal length the generator learned: the card's camera, and the
    one every photo is resampled to. ``rgb2cloud fit`` trains a large recording at a smaller
    scale; its card must name that camera, not the recording's.
    """
    native = open_source(config.data.train[0])[0].intrinsics
    scale = config.data.val_scale
    if scale == 1.0:
        return native
    return native.resized(round(native.width * scale), round(native.height * scale))


def validate(run: Run) -> None:
    """Score the generator on the validation frames at ``run.step``; keep ``best.pt`` if it is the best yet by
    ``train.select_metric`` (none is kept when that is null)."""
    if run.val_frames is None or run.camera is None or run.writer is None:
        return
    result, grid = score_generator(unwrap(run.generator), run.config, run.val_frames, run.camera)
    for key in METRIC_KEYS:
        run.writer.add_scalar(f"val/{key}", result[key], run.step)
    (run.out / "samples").mkdir(exist_ok=True)
    sample_grid(grid).save(run.out / "samples" / f"step_{run.step:07d}.png")
    metric = run.config.train.select_metric
    if metric is None:  # the last checkpoint is the result
        return
    score = -result[metric] if metric == "delta1" else result[metric]
    if run.best is None or score < run.best.score:
        run.best = Best(score, run.step, result)
        run.save("best.pt")


def log_losses(run: Run, losses: dict[str, float], images_per_s: float) -> None:
    """The step's losses, learning rate and speed to TensorBoard."""
    for key, value in losses.items():
        run.writer.add_scalar(f"loss/{key}", value, run.step)
    run.writer.add_scalar("lr", run.config.optim.lr_at(run.step - 1), run.step)
    run.writer.add_scalar("images_per_s", images_per_s, run.step)


def train_step(
    run: Run, step: int, batch: dict[str, torch.Tensor], gan_loss: GANLoss
) -> tuple[dict[str, torch.Tensor], float, int]:
    """Step ``step`` (from 0) on one batch: its losses, its seconds, and the images all ranks saw."""
    tick = time.perf_counter()
    for opt in (run.opt_g, run.opt_d):
        for group in opt.param_groups:
            group["lr"] = run.config.optim.lr_at(step) * group.get("lr_scale", 1.0)
    torch.manual_seed(step_seed(run.config.train.seed, step, run.ddp.rank))
    batch = {k: v.to(run.device, non_blocking=True) for k, v in batch.items()}
    networks, optimisers = (run.generator, run.discriminator), (run.opt_g, run.opt_d)
    losses = gan_step(*networks, optimisers, run.scaler, gan_loss, run.config.loss, batch, run.autocast)
    return losses, time.perf_counter() - tick, batch["rgb"].shape[0] * run.ddp.world_size


def _train(
    config: RunConfig,
    resume: bool,
    ddp: Distributed,
    report: Callable[[int, int], None] | None,
    deadline: float | None,
    revise: Revise | None = None,
) -> RunSummary:
    run = start_run(config, resume, ddp)
    loader = training_loader(config, ddp, run.step, pin_memory=run.device.type == "cuda")
    gan_loss = GANLoss(config.loss.gan_mode)
    if ddp.is_main and run.step == 0:
        validate(run)  # the untrained baseline, so every curve has a starting point
    run.generator.train()
    run.discriminator.train()
    batches = iter(loader)
    progress = tqdm(
        initial=run.step,
        total=config.train.steps,
        disable=not ddp.is_main or report is not None,
        desc="train",
        unit="step",
        dynamic_ncols=True,
    )
    # A resumed run has validated at each multiple of its spacing so far: the pacer reserves only those left.
    window_seconds, window_images, logged, validating = 0.0, 0, {}, 0.0
    validations = run.step // config.train.val_every
    began = time.perf_counter()
    while run.step < config.train.steps:
        losses, seconds, images = train_step(run, run.step, next(batches), gan_loss)
        run.train_seconds += seconds
        window_seconds += seconds
        window_images += images
        run.step += 1
        progress.update(1)
        busy = time.perf_counter() - began - validating
        if revise is not None and (revised := revise(run.step, busy, validating, validations)) is not None:
            config = run.config = revised
            progress.total = config.train.steps
        last = run.step >= config.train.steps or (deadline is not None and time.monotonic() >= deadline)
        if report is not None:
            report(run.step, config.train.steps)
        if ddp.is_main and (run.step % config.train.log_every == 0 or last):
            logged = {key: value.item() for key, value in losses.items()}
            rate = window_images / window_seconds
            log_losses(run, logged, rate)
            progress.set_postfix({k: f"{v:.3f}" for k, v in logged.items()} | {"img/s": f"{rate:.1f}"})
            window_seconds, window_images = 0.0, 0
        at_validation = run.step % config.train.val_every == 0
        at_checkpoint = run.step % config.train.checkpoint_every == 0
        if ddp.is_main and (at_validation or last):
            tick = time.perf_counter()
            validate(run)
            validating += time.perf_counter() - tick
            validations += 1
        if ddp.is_main and (at_checkpoint or last):
            run.save("last.pt")
        if ddp.world_size > 1 and (at_validation or at_checkpoint):
            dist.barrier()  # keep ranks together while rank 0 validates or saves
        if last:
            break
    progress.close()
    return finish(run, logged)


def finish(run: Run, last_losses: dict[str, float]) -> RunSummary:
    """The run's summary, written by rank 0 once every rank has gathered its weights' digest."""
    digests = rank_digests(run.ddp, unwrap(run.generator), unwrap(run.discriminator))
    summary = RunSummary(run.step, round(run.train_seconds, 1), run.hardware, run.best, digests, last_losses)
    if run.ddp.is_main:
        run.writer.close()
        (run.out / "summary.json").write_text(json.dumps(asdict(summary), indent=2) + "\n")
    if run.ddp.world_size > 1:
        dist.barrier()  # no rank leaves the group while another still writes or gathers
    return summary
