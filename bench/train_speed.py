"""How many training steps a minute this machine runs, for each way a step can be run.

    python bench/train_speed.py [--steps 6] [--threads N] [--markdown FILE]

One fit's training step (batch 4 of 240x320 crops, the bundled model's generator and
discriminators, the fit's losses) timed in one process, every variant on the same
batches, interleaved round by round so that a busy machine slows them alike. The table
gives the median step and its steps per minute as a ratio to fp32, with the CPU's
flags: bf16 is fast only where the CPU multiplies it in hardware (AVX512-BF16, AMX).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch

from contract.card import load_card
from trainer.config import RunConfig, migrate_config
from trainer.gan import Autocast, build_networks, gan_step
from trainer.losses import GANLoss
from trainer.machine import SPEED_FLAGS, cpu_description, cpu_flags

REPO = Path(__file__).resolve().parents[1]
BASE = REPO / "weights" / "rgb2cloud-7scenes" / "0.8.1"
#: (label, bf16 autocast, channels_last, adversarial): the ways one step can run.
VARIANTS = [
    ("fp32 (today)", False, False, True),
    ("bf16 autocast", True, False, True),
    ("fp32, channels_last", False, True, True),
    ("bf16 autocast, channels_last", True, True, True),
    ("fp32, no discriminator (L1 only)", False, False, False),
    ("bf16 autocast, no discriminator (L1 only)", True, False, False),
]


def base_config() -> RunConfig:
    """The bundled model's recipe at a fit's crop size (what ``rgb2cloud fit`` trains from)."""
    card = load_card(BASE)
    tree = migrate_config(card.training.config)
    tree["generator"] = card.generator.model_dump(mode="json")
    tree["inference"] = card.inference.model_dump(mode="json")
    tree["data"]["transform"]["size"] = [240, 320]
    return RunConfig.model_validate(tree)


def stepper(config: RunConfig, bf16: bool, channels_last: bool, adversarial: bool) -> Callable[[dict], None]:
    """One variant's networks, and a function that runs one training step of it on a batch."""
    loss = config.loss if adversarial else config.loss.model_copy(update={"gan": 0.0, "feature_matching": 0.0})
    generator, discriminator, opt_g, opt_d = build_networks(config, torch.device("cpu"))
    memory = torch.channels_last if channels_last else torch.contiguous_format
    generator.to(memory_format=memory)
    discriminator.to(memory_format=memory)
    precision = Autocast(bf16, torch.bfloat16)
    scaler = torch.amp.GradScaler("cpu", enabled=False)
    gan_loss = GANLoss(config.loss.gan_mode)

    def step(batch: dict) -> None:
        moved = {k: v.contiguous(memory_format=memory) for k, v in batch.items()}
        gan_step(generator, discriminator, (opt_g, opt_d), scaler, gan_loss, loss, moved, precision)

    return step


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=6, help="timed steps per variant (after one warm-up)")
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    config = base_config()
    h, w = config.data.transform.size
    torch.manual_seed(0)
    batch = {
        "rgb": torch.rand(4, 3, h, w) * 2 - 1,
        "depth": torch.rand(4, 1, h, w) * 2 - 1,
        "valid": (torch.rand(4, 1, h, w) > 0.1).float(),
    }
    steppers = [stepper(config, *variant[1:]) for variant in VARIANTS]
    seconds: list[list[float]] = [[] for _ in VARIANTS]
    for round_ in range(args.steps + 1):  # round 0 warms up every variant
        for i, step in enumerate(steppers):
            start = time.perf_counter()
            step(batch)
            if round_:
                seconds[i].append(time.perf_counter() - start)
    medians = [statistics.median(s) for s in seconds]
    flags = sorted(cpu_flags() & set(SPEED_FLAGS)) or ["none of " + ", ".join(SPEED_FLAGS)]
    rows = [
        f"| {label} | {1000 * m:.0f} | {60 / m:.0f} | {medians[0] / m:.2f}x |"
        for (label, *_), m in zip(VARIANTS, medians, strict=True)
    ]
    table = (
        f"Machine: {cpu_description()}, {args.threads} threads; flags: {', '.join(flags)}. One fit step: batch 4 "
        f"of {w}x{h}, {BASE.parent.name} {BASE.name}'s networks, median of {args.steps} steps each, interleaved.\n\n"
        "| step | ms | steps/min | vs fp32 |\n|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    print(table)
    if args.markdown:
        command = f"python bench/train_speed.py --steps {args.steps} --threads {args.threads}"
        args.markdown.write_text(f"# Training steps per minute\n\nMade by `{command}`.\n\n{table}")


if __name__ == "__main__":
    main()
