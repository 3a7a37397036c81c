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

import gc
import hashlib
import json
import os
import time
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

from trainer.checkpoint import load_checkpoint, save_checkpoint
from trainer.config import RunConfig, complete_config
from trainer.data.dataset import ConcatFrames, StepBatchSampler, TrainingSet
from trainer.data.sources import open_source
from trainer.evaluate import evaluate_frames
from trainer.inference import EagerGenerator, InferenceGraph
from trainer.losses import GANLoss, feature_matching, fill_holes, masked_l1, patch_weights
from trainer.machine import cpu_description
from trainer.networks import GlobalGenerator, MultiscaleDiscriminator
from trainer.visualize import sample_grid

#: Config sections that define the networks and their targets; resume refuses to change them.
FROZEN_ON_RESUME = ("generator", "discriminator", "depth", "loss")


@dataclass
class Distributed:
    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def setup_distributed(device_kind: str) -> Distributed:
    """Join the torchrun process group if launched by torchrun; otherwise run alone."""
    if "RANK" not in os.environ:
        return Distributed()
    backend = "nccl" if device_kind == "cuda" else "gloo"
    dist.init_process_group(backend)
    return Distributed(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", 0)))


def pick_device(choice: str, local_rank: int) -> torch.device:
    if choice == "cuda" and not torch.cuda.is_available():
        raise ValueError("train.device=cuda, but torch sees no CUDA device (use train.device=auto or cpu)")
    if choice == "cuda" or (choice == "auto" and torch.cuda.is_available()):
        torch.cuda.set_device(local_rank)
        return torch.device("cuda", local_rank)
    return torch.device("cpu")


def hardware_description(device: torch.device, world_size: int) -> str:
    if device.type == "cuda":
        return f"{world_size} x {torch.cuda.get_device_name(device)}"
    return f"CPU {cpu_description()}, {world_size} process(es), {torch.get_num_threads()} threads each"


def hardware_history(segments: list[list], step: int) -> str:
    """The card's hardware line: one machine, or each stretch of steps when a resume changed it.

    ``segments`` holds ``[first_step, hardware]`` pairs in order; ``step`` ends the last one.
    """
    if len(segments) == 1:
        return segments[0][1]
    ends = [start for start, _ in segments[1:]] + [step]
    return "; ".join(f"steps {start}-{end}: {hw}" for (start, hw), end in zip(segments, ends, strict=True))


def init_weights(module: nn.Module) -> None:
    """pix2pixHD's initialisation: conv weights ~ N(0, 0.02), biases 0."""
    if isinstance(module, nn.Conv2d | nn.ConvTranspose2d):
        nn.init.normal_(module.weight, 0.0, 0.02)
        if module.bias is not None:
            nn.init.zeros_(module.bias)


def step_seed(seed: int, step: int, rank: int) -> int:
    return int(np.random.SeedSequence([seed, step, rank]).generate_state(1)[0])


def weights_digest(*modules: nn.Module) -> str:
    """sha256 over every parameter and buffer, to compare ranks or runs exactly."""
    digest = hashlib.sha256()
    for module in modules:
        for name, tensor in sorted(module.state_dict().items()):
            digest.update(name.encode())
            digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


def _split(outputs: list[list[torch.Tensor]], n: int) -> tuple[list[list[torch.Tensor]], list[list[torch.Tensor]]]:
    """Split D's outputs for a [fake; real] batch into the fake and the real halves."""
    fake = [[t[:n] for t in scale] for scale in outputs]
    real = [[t[n:] for t in scale] for scale in outputs]
    return fake, real


def _unwrap(module: nn.Module) -> nn.Module:
    return module.module if isinstance(module, DistributedDataParallel) else module


def _check_resumable(saved: dict, config: RunConfig) -> None:
    saved, now = complete_config(saved), config.model_dump(mode="json")
    for section in FROZEN_ON_RESUME:
        if saved[section] != now[section]:
            raise ValueError(
                f"cannot resume: config section '{section}' differs from the checkpoint's "
                f"({saved[section]} vs {now[section]})"
            )


def train(config: RunConfig, resume: bool = False) -> dict:
    """Run (or continue) training; returns the run summary that is also written to disk."""
    ddp = setup_distributed("cuda" if config.train.device != "cpu" and torch.cuda.is_available() else "cpu")
    try:
        return _train(config, resume, ddp)
    finally:
        if ddp.world_size > 1:
            leave_process_group()


def leave_process_group() -> None:
    """Tear the process group down in a set order, while the interpreter is still whole.

    In CI, rank 0 of a finished CPU run once aborted at exit ("terminate called without
    an active exception", SIGABRT) after its last step. The DDP wrappers' reducers
    hold the group and its gloo threads; if they outlive ``destroy_process_group`` they
    are freed during interpreter shutdown in no set order. So every rank first meets the
    others (the barrier at the end of ``_train``), then the wrappers, gone with
    ``_train``'s frame or held in a cycle, are collected, and only then is the group destroyed.
    """
    gc.collect()
    dist.destroy_process_group()


def _train(config: RunConfig, resume: bool, ddp: Distributed) -> dict:
    device = pick_device(config.train.device, ddp.local_rank)
    if config.train.threads:
        torch.set_num_threads(config.train.threads)
    loop = config.train
    out = Path(loop.out_dir)
    ckpt_dir = out / "checkpoints"

    torch.manual_seed(loop.seed)  # identical initial weights on every rank
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
    use_amp = loop.amp and device.type == "cuda"
    amp_dtype = torch.bfloat16 if use_amp and torch.cuda.is_bf16_supported() else torch.float16
    scaler = torch.amp.GradScaler(device.type, enabled=use_amp and amp_dtype == torch.float16)

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

    frames = ConcatFrames([open_source(s) for s in config.data.train])
    val_frames = ConcatFrames([open_source(s) for s in config.data.val]) if config.data.val else None
    dataset = TrainingSet(frames, config.data.transform, config.depth, loop.seed)
    sampler = StepBatchSampler(len(frames), loop.batch_size, loop.seed, ddp.rank, ddp.world_size, start_step)
    loader = DataLoader(
        dataset,
        batch_sampler=sampler,
        num_workers=loop.num_workers,
        pin_memory=device.type == "cuda",
        persistent_workers=loop.num_workers > 0,
    )
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
        state = {
            "generator": _unwrap(generator).state_dict(),
            "discriminator": _unwrap(discriminator).state_dict(),
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
        return state

    def validate(step: int) -> dict | None:
        nonlocal best
        if val_frames is None:
            return None
        _unwrap(generator).eval()
        runner = EagerGenerator(InferenceGraph(_unwrap(generator), config.inference), config.generator.input_multiple)
        result, _, grid = evaluate_frames(
            lambda rgb: config.depth.decode(runner.predict_raw(rgb)),
            val_frames,
            min_m=config.data.eval_min_m,
            max_m=config.data.eval_max_m,
            scale=config.data.val_scale,
            samples=4,
        )
        _unwrap(generator).train()
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
        disable=not ddp.is_main,
        desc="train",
        unit="step",
        dynamic_ncols=True,
    )
    window_seconds, window_images, logged = 0.0, 0, {}
    for step in progress:
        tick = time.perf_counter()
        for opt in (opt_g, opt_d):
            for group in opt.param_groups:
                group["lr"] = config.optim.lr_at(step)
        torch.manual_seed(step_seed(loop.seed, step, ddp.rank))
        batch = {k: v.to(device, non_blocking=True) for k, v in next(batches).items()}
        x, real, valid = batch["rgb"], batch["depth"], batch["valid"]
        n = x.shape[0]

        # Generator: fool D and match its features on real pairs.
        with torch.autocast(device.type, dtype=amp_dtype, enabled=use_amp):
            fake = generator(x)
            real_filled = fill_holes(real, fake, valid)
            pairs = torch.cat([torch.cat([x, fake], 1), torch.cat([x, real_filled], 1)], 0)
            pred_fake, pred_real = _split(discriminator(pairs), n)
            weights = patch_weights(valid, pred_real)
            loss_g_gan = gan_loss(pred_fake, True)
            loss_fm = feature_matching(pred_fake, pred_real, weights)
            loss_g = loss_g_gan + config.loss.feature_matching * loss_fm
            loss_l1 = masked_l1(fake, real, valid) if config.loss.l1_depth > 0 else None
            if loss_l1 is not None:
                loss_g = loss_g + config.loss.l1_depth * loss_l1
        opt_g.zero_grad(set_to_none=True)
        scaler.scale(loss_g).backward()
        scaler.step(opt_g)

        # Discriminator: the same fake batch (detached) against real pairs with holes filled.
        with torch.autocast(device.type, dtype=amp_dtype, enabled=use_amp):
            pairs = torch.cat([torch.cat([x, fake.detach()], 1), torch.cat([x, real_filled], 1)], 0)
            pred_fake, pred_real = _split(discriminator(pairs), n)
            loss_d_fake = gan_loss(pred_fake, False)
            loss_d_real = gan_loss(pred_real, True, weights)  # the same cells as in the G step
            loss_d = 0.5 * (loss_d_fake + loss_d_real)
        opt_d.zero_grad(set_to_none=True)
        scaler.scale(loss_d).backward()
        scaler.step(opt_d)
        scaler.update()

        elapsed = time.perf_counter() - tick  # validation and saving below are not training time
        train_seconds += elapsed
        window_seconds += elapsed
        window_images += n * ddp.world_size
        done = step + 1
        if ddp.is_main and (done % loop.log_every == 0 or done == loop.steps):
            rate = window_images / window_seconds
            logged = {
                "G_gan": loss_g_gan.item(),
                "G_fm": loss_fm.item(),
                "D_real": loss_d_real.item(),
                "D_fake": loss_d_fake.item(),
            }
            if loss_l1 is not None:
                logged["G_l1"] = loss_l1.item()
            for key, value in logged.items():
                writer.add_scalar(f"loss/{key}", value, done)
            writer.add_scalar("lr", config.optim.lr_at(step), done)
            writer.add_scalar("images_per_s", rate, done)
            progress.set_postfix({k: f"{v:.3f}" for k, v in logged.items()} | {"img/s": f"{rate:.1f}"})
            window_seconds, window_images = 0.0, 0
        if ddp.is_main and (done % loop.val_every == 0 or done == loop.steps):
            validate(done)
        if ddp.is_main and (done % loop.checkpoint_every == 0 or done == loop.steps):
            save_checkpoint(ckpt_dir / "last.pt", checkpoint_state(done))
        if ddp.world_size > 1 and (done % loop.val_every == 0 or done % loop.checkpoint_every == 0):
            dist.barrier()  # keep ranks together while rank 0 validates or saves

    digest = weights_digest(_unwrap(generator), _unwrap(discriminator))
    digests = [digest]
    if ddp.world_size > 1:
        digests = [None] * ddp.world_size
        dist.all_gather_object(digests, digest)
    summary = {
        "steps": loop.steps,
        "train_seconds": round(train_seconds, 1),
        "hardware": hardware_history(segments, loop.steps),
        "best": best,
        "rank_weight_sha256": digests,
        "last_losses": logged,
    }
    if ddp.is_main:
        writer.close()
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if ddp.world_size > 1:
        dist.barrier()  # no rank leaves the group while another still writes or gathers
    return summary
