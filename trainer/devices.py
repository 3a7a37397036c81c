"""Where training runs: the device, torchrun's process group, and proof that the ranks agree.

``torchrun`` sets ``RANK``; without it a run is one process. The same code then runs on
one CPU, one GPU, or many processes on many nodes (gloo on CPU, NCCL on CUDA).
"""

from __future__ import annotations

import gc
import hashlib
import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel

from contract.errors import UserError
from trainer.machine import cpu_description


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
        raise UserError("train.device=cuda, but torch sees no CUDA device (use train.device=auto or cpu)")
    if choice == "cuda" or (choice == "auto" and torch.cuda.is_available()):
        torch.cuda.set_device(local_rank)
        return torch.device("cuda", local_rank)
    return torch.device("cpu")


def hardware_description(device: torch.device, world_size: int) -> str:
    if device.type == "cuda":
        return f"{world_size} x {torch.cuda.get_device_name(device)}"
    return f"CPU {cpu_description()}, {world_size} process(es), {torch.get_num_threads()} threads each"


def leave_process_group() -> None:
    """Tear the process group down in a set order, while the interpreter is still whole.

    The DDP wrappers' reducers hold the group and its gloo threads. If they outlive
    ``destroy_process_group``, they are freed during interpreter shutdown in no set order,
    and a finished rank can abort at exit ("terminate called without an active exception").
    So every rank first meets the others (the barrier at the end of ``trainer.train``'s run),
    then the wrappers, gone with the run's frame or held in a cycle, are collected, and only
    then is the group destroyed.
    """
    gc.collect()
    dist.destroy_process_group()


def weights_digest(*modules: nn.Module) -> str:
    """sha256 over every parameter and buffer, to compare ranks or runs exactly."""
    digest = hashlib.sha256()
    for module in modules:
        for name, tensor in sorted(module.state_dict().items()):
            digest.update(name.encode())
            digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


def rank_digests(ddp: Distributed, *modules: nn.Module) -> list[str]:
    """Every rank's ``weights_digest``, gathered, so the summary shows that the ranks agree."""
    digest = weights_digest(*modules)
    if ddp.world_size == 1:
        return [digest]
    digests = [None] * ddp.world_size
    dist.all_gather_object(digests, digest)
    return digests


def unwrap(module: nn.Module) -> nn.Module:
    """The module itself, out of its DistributedDataParallel wrapper if it has one."""
    return module.module if isinstance(module, DistributedDataParallel) else module
