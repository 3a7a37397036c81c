"""The training loop: one readable pass from config to checkpoints, alone or under torchrun.

    rgb2cloud train configs/7scenes.yaml                       # one process
    torchrun --nproc_per_node 2 -m cli train configs/...       # DDP, same code

Order of one step, as pix2pixHD: G is updated against the current D (cGAN +
mu * feature matching, + optional masked L1), then D against the same fake
batch. Each D forward is followed by exactly one backward, with the fake and
real halves in one batch, which keeps DistributedDataParallel's gradient
hooks simple. Every random draw in a step is seeded from (seed, step, rank),
so a resumed run repeats an uninterrupted one bit for bit on the same device.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import yaml
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from trainer.checkpoint import load_checkpoint, load_generator_weights, save_checkpoint
from trainer.config import LossConfig, RunConfig, complete_config
from trainer.data.dataset import ConcatFrames, StepBatchSampler, TrainingSet
from trainer.data.sources import open_source
from trainer.devices import (
    Distributed,
    hardware_description,
    hardware_history,
    leave_process_group,
    pick_device,
    rank_digests,
    setup_distributed,
    unwrap,
)
from trainer.evaluate import evaluate_frames
from trainer.inference import EagerGenerator, InferenceGraph
from trainer.losses import GANLoss, feature_matching, fill_holes, masked_l1, patch_weights
from trainer.networks import GlobalGenerator, MultiscaleDiscriminator
from trainer.visualize import sample_grid

#: Config sections that define the networks and their targets; resume refuses to change them.
FROZEN_ON_RESUME = ("generator", "discriminator", "depth", "loss")


def init_weights(module: nn.Module) -> None:
    """pix2pixHD's initialisation: conv weights ~ N(0, 0.02), biases 0."""
    if isinstance(module, nn.Conv2d | nn.ConvTranspose2d):
        nn.init.normal_(module.weight, 0.0, 0.02)
        if module.bias is not None:
            nn.init.zeros_(module.bias)


def step_seed(seed: int, step: int, rank: int) -> int:
    return int(np.random.SeedSequence([seed, step, rank]).generate_state(1)[0])


def _split(outputs: list[list[torch.Tensor]], n: int) -> tuple[list[list[torch.Tensor]], list[list[torch.Tensor]]]:
    """Split D's outputs for a [fake; real] batch into the fake and the real halves."""
    fake = [[t[:n] for t in scale] for scale in outputs]
    real = [[t[n:] for t in scale] for scale in outputs]
    return fake, real


def _check_resumable(saved: dict, config: RunConfig) -> None:
    saved, now = complete_config(saved), config.model_dump(mode="json")
    for section in FROZEN_ON_RESUME:
        if saved[section] != now[section]:
            raise ValueError(
                f"cannot resume: config section '{section}' differs from the checkpoint's "
                f"({saved[section]} vs {now[section]})"
            )


def train(
    config: RunConfig,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
    deadline: float | None = None,
) -> dict:
    """Run (or continue) training; returns the run summary that is also written to disk.

    ``progress(step, steps)`` after each step replaces the run's own progress bar (``fit``
    draws one bar for its whole command). At ``deadline`` (``time.monotonic()``), a
    single-process run saves its checkpoint and stops early: a wall-clock budget holds
    even when the machine runs slower than it was measured.
    """
    ddp = setup_distributed("cuda" if config.train.device != "cpu" and torch.cuda.is_available() else "cpu")
    if deadline is not None and ddp.world_size > 1:
        raise ValueError("a deadline stops one process; under torchrun the ranks would part ways")
    try:
        return _train(config, resume, ddp, progress, deadline)
    finally:
        if ddp.world_size > 1:
            leave_process_group()


@dataclass(frozen=True)
class Precision:
    """Mixed precision on CUDA (bf16 where supported, else fp16 with a gradient scaler); fp32 elsewhere."""

    enabled: bool
    dtype: torch.dtype

    @property
    def scaled(self) -> bool:
        """fp16 gradients need a scaler against underflow; bf16 and fp32 do not."""
        return self.enabled and self.dtype == torch.float16

    @classmethod
    def for_device(cls, device: torch.device, wanted: bool) -> Precision:
        enabled = wanted and device.type == "cuda"
        return cls(enabled, torch.bfloat16 if enabled and torch.cuda.is_bf16_supported() else torch.float16)


def build_networks(
    config: RunConfig, device: torch.device
) -> tuple[GlobalGenerator, MultiscaleDiscriminator, torch.optim.Adam, torch.optim.Adam]:
    """G and D with pix2pixHD's initialisation, seeded so every rank starts identical, and their Adams."""
    torch.manual_seed(config.train.seed)
    generator = GlobalGenerator(config.generator)
    discriminator = MultiscaleDiscriminator(
        config.discriminator, config.generator.input_nc + config.generator.output_nc
    )
    generator.apply(init_weights)
    discriminator.apply(init_weights)
    generator.to(device)
    discriminator.to(device)
    betas = (config.optim.beta1, config.optim.beta2)
    opt_g = torch.optim.Adam(generator.parameters(), lr=config.optim.lr, betas=betas)
    opt_d = torch.optim.Adam(discriminator.parameters(), lr=config.optim.lr, betas=betas)
    return generator, discriminator, opt_g, opt_d


def training_loader(config: RunConfig, ddp: Distributed, start_step: int, pin_memory: bool) -> DataLoader:
    """This rank's batches from ``start_step`` on, each rebuilt from the step number alone."""
    frames = ConcatFrames([reader for s in config.data.train for reader in [open_source(s)] * s.repeat])
    loop = config.train
    dataset = TrainingSet(frames, config.data.transform, config.depth, loop.seed)
    sampler = StepBatchSampler(len(frames), loop.batch_size, loop.seed, ddp.rank, ddp.world_size, start_step)
    return DataLoader(
        dataset,
        batch_sampler=sampler,
        num_workers=loop.num_workers,
        pin_memory=pin_memory,
        persistent_workers=loop.num_workers > 0,
    )


def gan_step(
    generator: nn.Module,
    discriminator: nn.Module,
    optimisers: tuple[torch.optim.Optimizer, torch.optim.Optimizer],
    scaler: torch.amp.GradScaler,
    gan_loss: GANLoss,
    loss: LossConfig,
    batch: dict[str, torch.Tensor],
    amp: Precision,
) -> dict[str, torch.Tensor]:
    """One pix2pixHD update: G against the current D, then D against the same fake batch; the losses."""
    opt_g, opt_d = optimisers
    x, real, valid = batch["rgb"], batch["depth"], batch["valid"]
    n = x.shape[0]
    device_type = x.device.type
    # Generator: fool D and match its features on real pairs.
    with torch.autocast(device_type, dtype=amp.dtype, enabled=amp.enabled):
        fake = generator(x)
        real_filled = fill_holes(real, fake, valid)
        pairs = torch.cat([torch.cat([x, fake], 1), torch.cat([x, real_filled], 1)], 0)
        pred_fake, pred_real = _split(discriminator(pairs), n)
        weights = patch_weights(valid, pred_real)
        losses = {"G_gan": gan_loss(pred_fake, True), "G_fm": feature_matching(pred_fake, pred_real, weights)}
        loss_g = losses["G_gan"] + loss.feature_matching * losses["G_fm"]
        if loss.l1_depth > 0:
            losses["G_l1"] = masked_l1(fake, real, valid)
            loss_g = loss_g + loss.l1_depth * losses["G_l1"]
    opt_g.zero_grad(set_to_none=True)
    scaler.scale(loss_g).backward()
    scaler.step(opt_g)

    # Discriminator: the same fake batch (detached) against real pairs with holes filled.
    with torch.autocast(device_type, dtype=amp.dtype, enabled=amp.enabled):
        pairs = torch.cat([torch.cat([x, fake.detach()], 1), torch.cat([x, real_filled], 1)], 0)
        pred_fake, pred_real = _split(discriminator(pairs), n)
        losses["D_fake"] = gan_loss(pred_fake, False)
        losses["D_real"] = gan_loss(pred_real, True, weights)  # the same cells as in the G step
        loss_d = 0.5 * (losses["D_fake"] + losses["D_real"])
    opt_d.zero_grad(set_to_none=True)
    scaler.scale(loss_d).backward()
    scaler.step(opt_d)
    scaler.update()
    return losses


def score_generator(
    generator: GlobalGenerator, config: RunConfig, frames: ConcatFrames
) -> tuple[dict, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Validation: the generator run as export will run it (its inference settings), on ``frames``."""
    generator.eval()
    runner = EagerGenerator(InferenceGraph(generator, config.inference), config.generator.input_multiple)
    result, _, grid = evaluate_frames(
        lambda rgb: config.depth.decode(runner.predict_raw(rgb)),
        frames,
        min_m=config.data.eval_min_m,
        max_m=config.data.eval_max_m,
        scale=config.data.val_scale,
        samples=4,
    )
    generator.train()
    return result, grid


def _train(
    config: RunConfig,
    resume: bool,
    ddp: Distributed,
    report: Callable[[int, int], None] | None,
    deadline: float | None,
) -> dict:
    device = pick_device(config.train.device, ddp.local_rank)
    if config.train.threads:
        torch.set_num_threads(config.train.threads)
    loop = config.train
    out = Path(loop.out_dir)
    ckpt_dir = out / "checkpoints"

    generator, discriminator, opt_g, opt_d = build_networks(config, device)
    if loop.init_from is not None and not resume:
        generator.load_state_dict(load_generator_weights(loop.init_from, config.generator))
    amp = Precision.for_device(device, loop.amp)
    scaler = torch.amp.GradScaler(device.type, enabled=amp.scaled)

    start_step, best, train_seconds = 0, None, 0.0
    segments: list[list] = []  # [first_step, hardware] per stretch of training on one setup
    if resume:
        state = load_checkpoint(ckpt_dir / "last.pt")
        _check_resumable(state["config"], config)
        generator.load_state_dict(state["generator"])
        discriminator.load_state_dict(state["discriminator"])
        opt_g.load_state_dict(state["opt_g"])
        opt_d.load_state_dict(state["opt_d"])
        scaler.load_state_dict(state["scaler"])
        start_step, best, train_seconds = state["step"], state["best"], state["train_seconds"]
        segments = state.get("hardware_segments") or [[0, state["hardware"]]]

    if ddp.world_size > 1:
        ids = [device.index] if device.type == "cuda" else None
        generator = DistributedDataParallel(generator, device_ids=ids)
        discriminator = DistributedDataParallel(discriminator, device_ids=ids)

    loader = training_loader(config, ddp, start_step, pin_memory=device.type == "cuda")
    val_frames = ConcatFrames([open_source(s) for s in config.data.val]) if config.data.val else None
    gan_loss = GANLoss(config.loss.gan_mode)

    writer = None
    if ddp.is_main:
        out.mkdir(parents=True, exist_ok=True)
        (out / "config.yaml").write_text(yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False))
        writer = SummaryWriter(out / "tensorboard", purge_step=start_step)
    hardware = hardware_description(device, ddp.world_size)
    if not segments or segments[-1][1] != hardware:
        segments.append([start_step, hardware])

    def checkpoint_state(step: int) -> dict:
        return {
            "generator": unwrap(generator).state_dict(),
            "discriminator": unwrap(discriminator).state_dict(),
            "opt_g": opt_g.state_dict(),
            "opt_d": opt_d.state_dict(),
            "scaler": scaler.state_dict(),
            "step": step,
            "best": best,
            "train_seconds": train_seconds,
            "hardware": hardware_history(segments, step),
            "hardware_segments": segments,
            "config": config.model_dump(mode="json"),
        }

    def validate(step: int) -> dict | None:
        nonlocal best
        if val_frames is None:
            return None
        result, grid = score_generator(unwrap(generator), config, val_frames)
        for key in ("rel", "rmse", "log10", "delta1", "delta2", "delta3", "pc_rmse_mean"):
            writer.add_scalar(f"val/{key}", result[key], step)
        (out / "samples").mkdir(exist_ok=True)
        sample_grid(grid).save(out / "samples" / f"step_{step:07d}.png")
        score = result[loop.select_metric]
        if loop.select_metric == "delta1":
            score = -score
        if best is None or score < best["score"]:
            best = {"score": score, "step": step, "metrics": result}
            save_checkpoint(ckpt_dir / "best.pt", checkpoint_state(step))
        return result

    if ddp.is_main and start_step == 0:
        validate(0)  # the untrained baseline, so every curve has a starting point
    generator.train()
    discriminator.train()
    batches = iter(loader)
    progress = tqdm(
        range(start_step, loop.steps),
        initial=start_step,
        total=loop.steps,
        disable=not ddp.is_main or report is not None,
        desc="train",
        unit="step",
        dynamic_ncols=True,
    )
    window_seconds, window_images, logged, done = 0.0, 0, {}, start_step
    for step in progress:
        tick = time.perf_counter()
        for opt in (opt_g, opt_d):
            for group in opt.param_groups:
                group["lr"] = config.optim.lr_at(step)
        torch.manual_seed(step_seed(loop.seed, step, ddp.rank))
        batch = {k: v.to(device, non_blocking=True) for k, v in next(batches).items()}
        losses = gan_step(generator, discriminator, (opt_g, opt_d), scaler, gan_loss, config.loss, batch, amp)
        n = batch["rgb"].shape[0]

        elapsed = time.perf_counter() - tick  # validation and saving below are not training time
        train_seconds += elapsed
        window_seconds += elapsed
        window_images += n * ddp.world_size
        done = step + 1
        last = done == loop.steps or (deadline is not None and time.monotonic() >= deadline)
        if report is not None:
            report(done, loop.steps)
        if ddp.is_main and (done % loop.log_every == 0 or last):
            rate = window_images / window_seconds
            logged = {key: value.item() for key, value in losses.items()}
            for key, value in logged.items():
                writer.add_scalar(f"loss/{key}", value, done)
            writer.add_scalar("lr", config.optim.lr_at(step), done)
            writer.add_scalar("images_per_s", rate, done)
            progress.set_postfix({k: f"{v:.3f}" for k, v in logged.items()} | {"img/s": f"{rate:.1f}"})
            window_seconds, window_images = 0.0, 0
        if ddp.is_main and (done % loop.val_every == 0 or last):
            validate(done)
        if ddp.is_main and (done % loop.checkpoint_every == 0 or last):
            save_checkpoint(ckpt_dir / "last.pt", checkpoint_state(done))
        if ddp.world_size > 1 and (done % loop.val_every == 0 or done % loop.checkpoint_every == 0):
            dist.barrier()  # keep ranks together while rank 0 validates or saves
        if last:
            break

    summary = {
        "steps": done,
        "train_seconds": round(train_seconds, 1),
        "hardware": hardware_history(segments, done),
        "best": best,
        "rank_weight_sha256": rank_digests(ddp, unwrap(generator), unwrap(discriminator)),
        "last_losses": logged,
    }
    if ddp.is_main:
        writer.close()
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if ddp.world_size > 1:
        dist.barrier()  # no rank leaves the group while another still writes or gathers
    return summary
