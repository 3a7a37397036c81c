"""Training batches that depend only on (seed, step): the key to exact resume and DDP.

``StepBatchSampler`` lays all samples of the run on one line: the global
position p = step * world_batch + rank * batch + j. Position p falls in epoch
p // N and picks that epoch's seeded permutation at p % N. The dataset seeds
its transforms from (seed, p). So any step's batch on any rank can be rebuilt
from the step number alone: resuming needs no sampler or RNG state, worker
count does not matter, and ranks never see the same sample in a step.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import torch
from torch.utils.data import Dataset, Sampler

from contract.codec import DepthEncoding
from recordings.frames import Frame, FrameReader
from trainer.config import TransformConfig
from trainer.data.transforms import apply_params, crop_size, sample_params
from trainer.data.views import ViewBank


def frame_to_tensors(frame: Frame, encoding: DepthEncoding) -> dict[str, torch.Tensor]:
    """RGB in [-1, 1], encoded depth in [-1, 1], validity mask, depth in metres."""
    valid = (frame.depth >= encoding.min_m) & (frame.depth <= encoding.max_m)
    return {
        "rgb": torch.from_numpy(frame.rgb.transpose(2, 0, 1).astype(np.float32) / 127.5 - 1.0),
        "depth": torch.from_numpy(encoding.encode(frame.depth)[None]),
        "valid": torch.from_numpy(valid[None].astype(np.float32)),
        "metres": torch.from_numpy(frame.depth[None].copy()),
    }


class ConcatFrames:
    """Several readers seen as one indexable sequence."""

    def __init__(self, readers: Sequence[FrameReader]):
        self.readers = list(readers)
        self.offsets = np.cumsum([0] + [len(r) for r in self.readers])

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def __getitem__(self, index: int) -> Frame:
        r = int(np.searchsorted(self.offsets, index, side="right") - 1)
        return self.readers[r][index - int(self.offsets[r])]


class TrainingSet(Dataset):
    """Indexed by (frame index, global position): augments with an RNG seeded by both.

    The crop size is drawn once per batch (position // batch_size names one rank's batch of
    one step), so a batch of mixed-extent views stacks into one tensor. With a bank of rendered
    views, a ``view_share`` of the samples is one of the frame's rendered views instead of the
    frame, drawn from the same (seed, position), and transformed as a frame would be.
    """

    def __init__(
        self,
        frames: ConcatFrames,
        transform: TransformConfig,
        encoding: DepthEncoding,
        seed: int,
        batch_size: int,
        multiple: int,
        views: ViewBank | None = None,
        view_share: float = 0.0,
    ):
        self.frames, self.transform, self.encoding, self.seed = frames, transform, encoding, seed
        self.batch_size, self.multiple = batch_size, multiple
        self.views, self.view_share = views, view_share
        # A view stored at a share of its frame's size is zoomed by as much more, to the same pixels as the frame.
        self.view_transform = transform
        if views is not None and views.scale != 1:
            zoom = tuple(s / views.scale for s in transform.scale)
            self.view_transform = transform.model_copy(update={"scale": zoom})

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, key: tuple[int, int]) -> dict[str, torch.Tensor]:
        index, position = key
        frame, transform = None, self.transform
        if self.views is not None:
            pick = np.random.default_rng([self.seed, position, 2])
            if pick.random() < self.view_share:
                frame = self.views.view(index, int(pick.integers(self.views.per_frame)))
                transform = self.view_transform
        if frame is None:
            frame = self.frames[index]
        batch_rng = np.random.default_rng([self.seed, position // self.batch_size, 1])
        crop = crop_size(batch_rng, self.transform, self.multiple)
        rng = np.random.default_rng([self.seed, position])
        params = sample_params(rng, transform, *frame.depth.shape, crop)
        return frame_to_tensors(apply_params(frame, params), self.encoding)


class StepBatchSampler(Sampler[list[tuple[int, int]]]):
    """Endless batches of (frame index, global position) for one rank, from ``start_step``."""

    def __init__(self, size: int, batch_size: int, seed: int, rank: int = 0, world_size: int = 1, start_step: int = 0):
        self.size, self.batch_size, self.seed = size, batch_size, seed
        self.rank, self.world_size, self.start_step = rank, world_size, start_step
        self._perms: dict[int, np.ndarray] = {}

    def _permutation(self, epoch: int) -> np.ndarray:
        if epoch not in self._perms:
            self._perms = {epoch: np.random.default_rng([self.seed, epoch, 7]).permutation(self.size)}
        return self._perms[epoch]

    def batch_for_step(self, step: int) -> list[tuple[int, int]]:
        first = (step * self.world_size + self.rank) * self.batch_size
        batch = []
        for position in range(first, first + self.batch_size):
            epoch, offset = divmod(position, self.size)
            batch.append((int(self._permutation(epoch)[offset]), position))
        return batch

    def __iter__(self) -> Iterator[list[tuple[int, int]]]:
        step = self.start_step
        while True:
            yield self.batch_for_step(step)
            step += 1
