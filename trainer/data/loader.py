"""A run's training batches: its train frames, its bank of rendered views, and a loader whose every batch is
rebuilt from the step number alone (``trainer.data.dataset``), for ``train`` and for fit's measurements."""

from __future__ import annotations

from pathlib import Path

import torch.distributed as dist
from torch.utils.data import DataLoader

from trainer.config import RunConfig
from trainer.data.dataset import ConcatFrames, StepBatchSampler, TrainingSet
from trainer.data.sources import open_source
from trainer.data.views import ViewBank, render_scale, view_bank
from trainer.devices import Distributed


def training_frames(config: RunConfig) -> ConcatFrames:
    """The run's train frames: every train source, each as many times as its ``repeat``."""
    return ConcatFrames([reader for s in config.data.train for reader in [open_source(s)] * s.repeat])


def training_views(config: RunConfig, frames: ConcatFrames, ddp: Distributed | None = None) -> ViewBank | None:
    """The run's bank of rendered views (``data.views``) in ``out_dir/views``, made or found there; None if unused.

    Under torchrun rank 0 renders it and the other ranks read what it made.
    """
    views, settings = config.data.views, config.train
    if views.share == 0:
        return None
    ddp = ddp or Distributed()
    folder, scale = Path(settings.out_dir) / "views", render_scale(config.data.transform)
    bank = view_bank(frames, views, settings.seed, folder, scale) if ddp.rank == 0 else None
    if ddp.world_size > 1:
        dist.barrier()
    return bank or view_bank(frames, views, settings.seed, folder, scale)


def training_loader(config: RunConfig, ddp: Distributed, start_step: int, pin_memory: bool) -> DataLoader:
    """This rank's batches from ``start_step`` on, each rebuilt from the step number alone."""
    frames = training_frames(config)
    settings = config.train
    dataset = TrainingSet(
        frames,
        config.data.transform,
        config.depth,
        settings.seed,
        settings.batch_size,
        config.generator.core_multiple,
        training_views(config, frames, ddp),
        config.data.views.share,
    )
    sampler = StepBatchSampler(len(frames), settings.batch_size, settings.seed, ddp.rank, ddp.world_size, start_step)
    return DataLoader(
        dataset,
        batch_sampler=sampler,
        num_workers=settings.num_workers,
        pin_memory=pin_memory,
        persistent_workers=settings.num_workers > 0,
    )
