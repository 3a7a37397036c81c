"""How good a fit gets in how many minutes: each development site, each budget, each starting point.

    python bench/fit_sites.py [--budgets 5 10 20 30] [--starts default imagenet rooms 0.8.0]
                              [--sites aims-lab mosd-tabletop]
                              [--markdown docs/fit-benchmark.md] [--curve docs/fit-benchmark.png]

Each cell is one ``rgb2cloud fit`` run in its own process, on this machine, with the
site's held-out frames scored once at its end (δ1, REL, point-cloud RMSE), beside the
starting model zero-shot and the best image-free baseline from the same run's card.
The ``default`` start is what ``fit`` starts from without ``--from`` (the bundled base), with fit's default
recipe; ``imagenet`` is ``--from imagenet`` (ImageNet's Lite0 under a fresh U-Net decoder), and ``0.8.0`` an
older bundled kitchen model. No site is one its starting model saw: the bundled versions saw only 7-Scenes
RedKitchen, and the ``rooms`` start is, for each site, ``bench/rooms-base.yaml`` trained without that site (leave
one site out; trained and published once, then reused for every budget).
Runs and their published versions go to ``runs/bench-fit/``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from harness.fitting import DATA, REPO, SITES

STARTS = ("default", "imagenet", "rooms", "0.8.0")
BUNDLED = REPO / "weights" / "rgb2cloud-7scenes"
ROOMS_CONFIG = REPO / "bench" / "rooms-base.yaml"
SEVEN_SCENES = DATA / "7scenes-redkitchen"
OUT = REPO / "runs" / "bench-fit"


def cli(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, check=True)


def rooms_without(site: str) -> Path:
    """The rooms base trained on every site but ``site``, published once into the bench's registry."""
    import yaml

    name = f"rooms-without-{site}"
    target = OUT / "registry" / name / "0.1.0"
    if target.is_dir():
        return target
    tree = yaml.safe_load(ROOMS_CONFIG.read_text())
    tree["data"]["train"] = [s for s in tree["data"]["train"] if Path(s["root"]).name != site]
    run = OUT / "bases" / name
    tree["train"]["out_dir"] = str(run)
    run.mkdir(parents=True, exist_ok=True)
    (run / "config.yaml").write_text(yaml.safe_dump(tree, sort_keys=False))
    cli("train", str(run / "config.yaml"), *(["--resume"] if (run / "checkpoints" / "last.pt").is_file() else []))
    checkpoint = str(run / "checkpoints" / "last.pt")
    colour = str(tree["data"]["train"][0]["colour_camera"])
    cli("evaluate", checkpoint, "--format", "7scenes", "--root", str(SEVEN_SCENES), "--frames", "850-999",
        "--colour-camera", colour, "--out", str(run / "kitchen-test"))  # fmt: skip
    metrics, photo = str(run / "kitchen-test" / "metrics.json"), str(SEVEN_SCENES / "frame-000900.color.jpg")
    cli("export", checkpoint, "--name", name, "--version", "0.1.0", "--metrics", metrics,
        "--parity-image", photo, "--registry", str(OUT / "registry"))  # fmt: skip
    return target


def start_options(site: str, start: str) -> list[str]:
    """``fit``'s ``--from`` for a start: none for fit's default."""
    if start == "default":
        return []
    if start == "imagenet":
        return ["--from", "imagenet"]
    return ["--from", str(rooms_without(site)) if start == "rooms" else str(BUNDLED / start)]


def fit_once(site: str, start: str, budget: float) -> tuple[dict, float]:
    """One fit in a fresh process; its card's held-out rows by label, and the minutes it took."""
    from contract.card import load_card

    name = f"{site}-{start.replace('.', '-')}-{budget:g}min"
    registry = OUT / "registry"
    args = [*SITES[site], "--name", name, "--budget", f"{budget:g}", *start_options(site, start)]
    args += ["--registry", str(registry), "--out", str(OUT / name)]
    began = time.monotonic()
    cli("fit", *args)
    minutes = (time.monotonic() - began) / 60
    card = load_card(registry / name / "0.1.0")
    return {m.label or "fitted": m for m in card.metrics}, minutes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budgets", type=float, nargs="+", default=[5, 10, 20, 30])
    parser.add_argument("--starts", nargs="+", default=list(STARTS), choices=list(STARTS))
    parser.add_argument("--sites", nargs="+", default=list(SITES), choices=list(SITES))
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    parser.add_argument("--curve", type=Path, help="save δ1 against minutes as a PNG here")
    args = parser.parse_args()

    from trainer.machine import cpu_description

    rows, curves = [], {}
    for site in args.sites:
        for start in args.starts:
            for budget in args.budgets:
                scores, minutes = fit_once(site, start, budget)
                fitted = scores["fitted"]
                zero_shot = next((m for label, m in scores.items() if "zero-shot" in label), None)
                baseline = max(
                    (m for label, m in scores.items() if label.startswith("baseline")), key=lambda m: m.delta1
                )
                rows.append(
                    f"| {site} | {start} | {budget:g} | {minutes:.1f} | {fitted.delta1:.3f} | {fitted.rel:.3f} | "
                    f"{fitted.pc_rmse_mean:.3f} | {f'{zero_shot.delta1:.3f}' if zero_shot else '—'} | "
                    f"{baseline.delta1:.3f} / {baseline.rel:.3f} |"
                )
                curves.setdefault(f"{site}, from {start}", []).append((budget, fitted.delta1))
                print(rows[-1], flush=True)
    budgets = " ".join(f"{b:g}" for b in args.budgets)
    command = f"python bench/fit_sites.py --budgets {budgets} --starts {' '.join(args.starts)}"
    command += f" --sites {' '.join(args.sites)}"
    table = (
        f"Machine: {cpu_description()}. Held-out frames only, scored once per run; the best image-free baseline "
        "is the better of the train median and the per-pixel train median on δ1.\n\n"
        "| site | start | budget (min) | took (min) | δ1 | REL | PC RMSE (m) | start, zero-shot δ1 | "
        "best baseline δ1 / REL |\n|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    print(table)
    if args.markdown:
        args.markdown.write_text(f"# Fitting a site: quality against minutes\n\nMade by `{command}`.\n\n{table}")
    if args.curve:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4))
        for label, points in curves.items():
            ax.plot(*zip(*points, strict=True), marker="o", label=label)
        ax.set_xlabel("budget (minutes, 2 CPU cores)")
        ax.set_ylabel("δ1 on held-out frames")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(args.curve, dpi=120)


if __name__ == "__main__":
    main()
