"""Fit-quality levers, each judged by the rule in docs/research.md: 10-minute fits on the development sites.

    python bench/fit_levers.py [--levers baseline bf16 ...] [--budget 10] [--seeds 0 2] [--markdown FILE]

The baseline is the recipe before these experiments (0.8.1's cGAN) fitted for the budget. A quality
lever trains the step count of the lever it is measured against (``fit --steps``), so a busy machine
cannot decide a quality comparison: the baseline, or a kept lever it builds on. A speed lever is
fitted for the same wall clock, its plan measured as fit measures it. Each lever is a set of
``fit --set`` changes to the start's recipe. Every lever is fitted at each of ``--seeds`` (``train.seed``),
seed after seed, so that the levers of one seed run side by side; a lever is compared with the lever it is
measured against at the same seed, and judged on its mean over the seeds. A ``gain`` lever is kept only if
aims-lab δ1 rises by at least 0.01 and mosd-tabletop δ1 falls by no more than 0.005, and aims-lab rises at
every seed (the seeds agree). A ``no-worse`` lever (a start chosen for views no site here shows) is kept
unless its mean falls by more than 0.01 on aims-lab or 0.005 on mosd-tabletop.
Runs and their published versions go to ``runs/bench-levers/``; a fit already published is reused.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

from harness.fitting import REPO, SITES, fit_once, report
from trainer.fit.start import IMAGENET_RECIPE

OUT = REPO / "runs" / "bench-levers"
GAIN, COST = 0.01, 0.005


@dataclass(frozen=True)
class Lever:
    """One change to the recipe: its ``fit --set`` overrides, and whether it is judged by speed or quality."""

    name: str
    kind: str  # "speed" (same wall clock) or "quality" (same steps)
    changes: tuple[str, ...]
    why: str
    #: The lever this one is measured against: its steps (for a quality lever) and its scores (for the rule).
    on: str = "baseline"
    #: Other ``fit`` options, such as where it starts (``--from``); none: fit's default start.
    options: tuple[str, ...] = ()
    #: Scores recorded on the same machine type by the table the lever cites, used in place of fitting it
    #: again (``--refit`` fits it): per site, its steps, δ1 and REL.
    recorded: dict[str, dict] | None = None
    #: How it is judged against ``on``: "gain" (it must win, at every seed), "no-worse" (it must not lose) or
    #: "within" (the same depth, within COST on both sites).
    rule: str = "gain"


# The recipe the experiments started from, spelled out, so that the table reruns whatever fit's default
# has become since: 0.8.1's, with its cGAN and feature matching, in fp32 (on a GPU too). bf16 autocast on
# a CPU, alone and on top of no-discriminator, was measured at commit f0068cb (where ``train.amp`` meant
# it on a CPU with AVX512-BF16 or AMX), not kept, and removed: docs/research.md.
FP32 = ("train.amp=false",)
GAN = ("loss.gan=1", "loss.feature_matching=10")
L1_ALONE = ("loss.gan=0", "loss.feature_matching=0")
FROM_0_9_0 = ("--from", str(REPO / "weights" / "rgb2cloud-7scenes" / "0.9.0"))
# The pretrained U-Net base as `rgb2cloud train configs/rgb2cloud-7scenes-1.0.0.yaml` and `rgb2cloud export ...
# --name rgb2cloud-7scenes-unet --version 1.0.0 --registry runs/weights` make it (docs/research.md): not bundled.
FROM_1_0_0 = ("--from", str(REPO / "runs" / "weights" / "rgb2cloud-7scenes-unet" / "1.0.0"))
# The frozen ImageNet start (``--from imagenet``, measured against fit's default): 0.9.0's recipe with the base's
# U-Net on ImageNet's Lite0; UNET is that start's generator (trainer.fit.start's recipe without its frozen encoder).
FROM_IMAGENET = ("--from", "imagenet")
UNET = tuple(option for option in IMAGENET_RECIPE if option.startswith("generator."))
#: Fits from 0.9.0 at 0.8.1's 10-minute plan on an AMD EPYC with 2 cores: docs/quality.md, "Fits from it".
FITS_FROM_0_9_0 = {
    "aims-lab": {"steps": 513, "delta1": 0.813, "rel": 0.199},
    "mosd-tabletop": {"steps": 539, "delta1": 0.976, "rel": 0.043},
}
LEVERS = {
    lever.name: lever
    for lever in [
        Lever("baseline", "both", (*FP32, *GAN), "the recipe before these experiments"),
        Lever(
            "no-discriminator",
            "speed",
            (*FP32, *L1_ALONE),
            "the masked L1 alone: no discriminator forward and backward, twice per step",
        ),
        Lever(
            "narrower-views",
            "quality",
            (*FP32, *GAN, "data.transform.size=[176,240]"),
            "crops of 0.75 of the frame per side at the same focal length: views narrower than the whole frame",
        ),
        Lever(
            "regression-adam",
            "quality",
            (*FP32, *L1_ALONE, "optim.lr=0.0005", "optim.beta1=0.9"),
            "pix2pix's lr 2e-4 and beta1 0.5 keep an adversarial game stable; the L1 alone is a plain regression, "
            "and a few hundred steps from a trained start can take larger, smoother Adam steps",
            on="no-discriminator",
        ),
        # Issue 60's levers (docs/research.md, "A generator that has seen the world"): each at the same wall clock.
        Lever(
            "from-0-9-0", "both", (), "today's fit from the bundled 0.9.0", "from-0-9-0", FROM_0_9_0, FITS_FROM_0_9_0
        ),
        Lever("from-1-0-0", "speed", (), "the pretrained U-Net base, fit's recipe as it is", "from-0-9-0", FROM_1_0_0),
        Lever(
            "from-imagenet",
            "speed",
            (*UNET, "optim.encoder_lr_scale=1"),
            "ImageNet's encoder and a fresh decoder (the base's U-Net): no kitchen in between",
            "from-0-9-0",
            FROM_IMAGENET,
        ),
        # 3 and 4 build on the better of 1 and 2: from ImageNet (docs/research.md).
        Lever(
            "frozen-encoder",
            "speed",
            (*UNET, "optim.encoder_lr_scale=0"),
            "ImageNet's encoder and its BatchNorm statistics kept as they are: only the decoder learns the room",
            "from-imagenet",
            FROM_IMAGENET,
        ),
        # Issue 68, 1: the frozen start again, beside today's default at two seeds, judged as a start: it is
        # kept unless it loses (0.08-0.12 δ1 ahead on a held-out office that no one here tuned for).
        Lever(
            "frozen-start",
            "speed",
            (*UNET, "optim.encoder_lr_scale=0"),
            "ImageNet's Lite0 U-Net with its encoder frozen, in place of the kitchen's 0.9.0",
            "from-0-9-0",
            FROM_IMAGENET,
            rule="no-worse",
        ),
        # Issue 68, 2: on the kept start, half of each batch a train frame seen from a nearby camera (data.views).
        Lever(
            "rendered-views",
            "speed",
            (*UNET, "optim.encoder_lr_scale=0", "data.views.share=0.5"),
            "half of each batch rendered from nearby cameras through the frame's own depth: forward by up to 45% "
            "of its median depth or back by 15%, sideways 10%, turned 8 degrees (roll 4), three views a frame",
            "frozen-start",
            FROM_IMAGENET,
        ),
        # The same on today's start from 0.9.0, where the rule keeps that start instead.
        Lever(
            "views-on-0-9-0",
            "speed",
            ("data.views.share=0.5",),
            "rendered-views' views on the start from the bundled 0.9.0",
            "from-0-9-0",
            FROM_0_9_0,
        ),
        # Issue 68, 4 and 5: the views' share and their forward reach, one at a time, against the better of
        # views-on-0-9-0 and its start (the start: views lost on mosd-tabletop at both seeds).
        Lever(
            "views-quarter",
            "speed",
            ("data.views.share=0.25",),
            "views-on-0-9-0's views in a quarter of each batch in place of half",
            "from-0-9-0",
            FROM_0_9_0,
        ),
        Lever(
            "views-reach",
            "speed",
            ("data.views.share=0.5", "data.views.forward=0.7"),
            "views-on-0-9-0's views moved forward by up to 70% of the frame's median depth in place of 45%",
            "from-0-9-0",
            FROM_0_9_0,
        ),
        # Issue 68, 3: with neither start nor views kept, the loss, against today's default.
        Lever(
            "silog",
            "speed",
            ("loss.silog=100", "loss.l1_depth=0"),
            "the scale-invariant log loss (SILog, lambda 0.85: part of each image's scale kept) in place of the "
            "masked L1, at the L1's weight",
            "from-0-9-0",
            FROM_0_9_0,
        ),
        # Issue 70, 4: a generator made for live, kept only if its held-out δ1 stays within COST on both sites.
        Lever(
            "live-half",
            "speed",
            (),
            "trained and served at 320x240 (a quarter of the pixels): the service resamples every photo to it",
            "from-0-9-0",
            (*FROM_0_9_0, "--pixels", "320x240"),
            rule="within",
        ),
        Lever(
            "slow-encoder",
            "speed",
            (*UNET, "optim.encoder_lr_scale=0.1"),
            "ImageNet's encoder learning at a tenth of the decoder's rate",
            "from-imagenet",
            FROM_IMAGENET,
        ),
        # 5 builds on the best so far: today's fit from 0.9.0. Both development sites are 640x480, which fit trains
        # at 0.5 of their pixels (work_scale 2): its zooms are 1-1.1x that, these 1-1.3x.
        Lever(
            "stronger-zooms",
            "speed",
            ("data.transform.scale=[0.5,0.65]",),
            "whole-frame crops showing 77-100% of the frame at up to 1.3x its focal length, for views the recording "
            "did not see (fit's own zooms stop at 1.1x)",
            "from-0-9-0",
            FROM_0_9_0,
        ),
        # 7, written down before its run: fit chooses its checkpoint on 10% of the train part (14 frames on
        # aims-lab) at four validations; the lever publishes the last one instead.
        Lever(
            "last-checkpoint",
            "speed",
            ("data.val=[]",),
            "no checkpoint chosen on the selection frames: the last one is published",
            "from-0-9-0",
            FROM_0_9_0,
        ),
    ]
}


def fit_site(lever: Lever, site: str, budget: float, steps: int | None, seed: int) -> dict:
    """One fit of ``site`` with ``lever`` at ``seed``; its held-out δ1 and REL and the steps it trained."""
    from contract.card import load_card

    name = f"{lever.name}-{site}" + (f"-seed{seed}" if seed else "")
    changes = (*lever.changes, f"train.seed={seed}")
    options = [*SITES[site][1:], "--budget", f"{budget:g}", *(a for c in changes for a in ("--set", c))]
    options += lever.options
    if steps is not None:
        options += ["--steps", str(steps)]
    version = fit_once(Path(SITES[site][0]), name, OUT, *options)
    fitted = next(m for m in load_card(version).metrics if m.label is None)
    plan = json.loads((OUT / "runs" / name / "fit.json").read_text())["plan"]
    return {"delta1": fitted.delta1, "rel": fitted.rel, "steps": plan["steps"]}


def mean(scores: dict[int, dict[str, dict]], site: str, key: str) -> float:
    """A lever's mean of one score on one site over the seeds it was fitted at."""
    return sum(s[site][key] for s in scores.values()) / len(scores)


def verdict(lever: Lever, scores: dict[int, dict[str, dict]], base: dict[int, dict[str, dict]]) -> str:
    """The rule, on means over seeds against the lever's ``on`` (each seed against the same seed's fit).

    "gain": aims-lab up by GAIN and mosd-tabletop down by no more than COST, and aims-lab up at every seed.
    "no-worse": aims-lab down by no more than GAIN and mosd-tabletop by no more than COST.
    "within": neither site down by more than COST (a cheaper generator for the same depth).
    """
    if lever.name == lever.on:
        return "—"
    gain = mean(scores, "aims-lab", "delta1") - mean(base, "aims-lab", "delta1")
    cost = mean(base, "mosd-tabletop", "delta1") - mean(scores, "mosd-tabletop", "delta1")
    if lever.rule == "within":
        return "kept" if gain >= -COST and cost <= COST else "not kept"
    if lever.rule == "no-worse":
        return "kept" if gain >= -GAIN and cost <= COST else "not kept"
    agree = all(scores[seed]["aims-lab"]["delta1"] > base[seed]["aims-lab"]["delta1"] for seed in scores)
    return "kept" if gain >= GAIN and cost <= COST and agree else "not kept"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levers", nargs="+", default=list(LEVERS), choices=list(LEVERS))
    parser.add_argument("--budget", type=float, default=10.0, help="minutes of each fit")
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    parser.add_argument("--refit", action="store_true", help="fit levers with recorded scores again")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0], help="train.seed of each fit (default: 0)")
    args = parser.parse_args()

    from trainer.machine import cpu_description

    measured: dict[tuple[str, int], dict[str, dict]] = {}

    def scores_of(name: str, seed: int) -> dict[str, dict]:
        """A lever's fits on every site at one seed, after the fits of the lever it is measured against."""
        if (name, seed) not in measured:
            lever = LEVERS[name]
            base = None if name == lever.on else scores_of(lever.on, seed)
            fixed = lever.kind == "quality" and base is not None
            if lever.recorded is not None and not args.refit:
                measured[name, seed] = lever.recorded
                return measured[name, seed]
            measured[name, seed] = {
                site: fit_site(lever, site, args.budget, base[site]["steps"] if fixed else None, seed) for site in SITES
            }
        return measured[name, seed]

    for seed in args.seeds:  # seed after seed: the levers of one seed fitted side by side
        for name in args.levers:
            scores_of(name, seed)
    rows = []
    for name in args.levers:
        lever = LEVERS[name]
        scores = {seed: scores_of(name, seed) for seed in args.seeds}
        base = {seed: scores_of(lever.on, seed) for seed in args.seeds}
        for seed in args.seeds:
            cells = " | ".join(f"{s['steps']} | {s['delta1']:.3f} | {s['rel']:.3f}" for s in scores[seed].values())
            delta = " | ".join(f"{scores[seed][site]['delta1'] - base[seed][site]['delta1']:+.3f}" for site in SITES)
            rows.append(f"| {name} | {seed} | {cells} | {delta} | |")
        cells = " | ".join(
            f"{sum(s[site]['steps'] for s in scores.values()) / len(scores):.0f} | "
            f"{mean(scores, site, 'delta1'):.3f} | {mean(scores, site, 'rel'):.3f}"
            for site in SITES
        )
        delta = " | ".join(f"{mean(scores, site, 'delta1') - mean(base, site, 'delta1'):+.3f}" for site in SITES)
        rows.append(f"| **{name}** | mean | {cells} | {delta} | {verdict(lever, scores, base)} ({lever.rule}) |")
        print("\n".join(rows[-len(args.seeds) - 1 :]), flush=True)
    levers = "\n".join(
        f"- {name} ({LEVERS[name].kind}, against {LEVERS[name].on}): "
        + (", ".join(f"`{c}`" for c in LEVERS[name].changes + LEVERS[name].options) or "fit's recipe")
        for name in args.levers
    )
    table = (
        f"Machine: {cpu_description()}. {args.budget:g}-minute fits (from fit's default start unless a lever says "
        "otherwise) at each seed (`train.seed`); held-out δ1 and REL; "
        "a quality lever trains the steps of the lever it is measured against at the same seed, a speed lever the "
        "steps its own plan fits in the budget. Δ is against the lever it is measured against, at the same seed "
        "(the mean row: between the means).\n\n"
        f"{levers}\n\n"
        "| lever | seed | aims-lab steps | δ1 | REL | mosd-tabletop steps | δ1 | REL | Δ aims-lab δ1 | "
        "Δ mosd-tabletop δ1 | verdict |\n|---|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    seeds = " ".join(str(s) for s in args.seeds)
    command = f"python bench/fit_levers.py --levers {' '.join(args.levers)} --budget {args.budget:g} --seeds {seeds}"
    command += " --refit" if args.refit else ""
    report(table, args.markdown, "Fit-quality levers", command)


if __name__ == "__main__":
    main()
