"""Fits from each kitchen base, judged by the rule in docs/research.md: is a new base as good a start?

    python bench/fit_bases.py --bases weights/rgb2cloud-7scenes/0.9.0 [--steps aims-lab=513 mosd-tabletop=539]

Every base is fitted on both development sites with fit's default recipe and the same number of steps
on each site (``fit --steps``): by default the steps that the recorded 0.8.1 row of the rule's table
trained in 10 minutes (docs/research.md, experiment 5, which is fit's default recipe today), so a busy
machine cannot decide. Each row is compared with the 0.8.1 row recorded there: a new base is "not
worse" when aims-lab δ1 falls by no more than 0.005 and mosd-tabletop δ1 by no more than 0.005.
Runs and their published versions go to ``runs/bench-bases/``; a fit already published is reused.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from harness.fitting import REPO, SITES, fit_once, report

OUT = REPO / "runs" / "bench-bases"
#: The rule's recorded fits from 0.8.1 with today's default recipe (docs/research.md, experiment 5):
#: steps, δ1, REL per site.
RECORDED_0_8_1 = {"aims-lab": (513, 0.803, 0.194), "mosd-tabletop": (539, 0.976, 0.039)}
COST = 0.005


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bases", type=Path, nargs="+", required=True, help="published version folders")
    parser.add_argument("--steps", nargs="+", default=[f"{s}={r[0]}" for s, r in RECORDED_0_8_1.items()])
    parser.add_argument("--sites", nargs="+", default=list(SITES), choices=list(SITES))
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    args = parser.parse_args()
    steps = {site: int(n) for site, n in (item.split("=") for item in args.steps)}

    from contract.card import load_card
    from trainer.machine import cpu_description

    rows = [
        "| rgb2cloud-7scenes 0.8.1 (recorded) | "
        + " | ".join(f"{s} | {d:.3f} | {r:.3f}" for s, d, r in RECORDED_0_8_1.values())
        + " | — | — | — |"
    ]
    for base in args.bases:
        card = load_card(base)
        scores = {}
        for site in args.sites:
            recording, *options = SITES[site]
            name = f"{card.name}-{card.version.replace('.', '-')}-{site}"
            options += ["--from", str(base), "--steps", str(steps[site]), "--budget", "10"]
            version = fit_once(Path(recording), name, OUT, *options)
            fitted = next(m for m in load_card(version).metrics if m.label is None)
            scores[site] = (steps[site], fitted.delta1, fitted.rel)
        change = {site: scores[site][1] - RECORDED_0_8_1[site][1] for site in args.sites}
        judged = "not worse" if min(change.values()) >= -COST else "worse"
        rows.append(
            f"| {card.name} {card.version} | "
            + " | ".join(f"{s} | {d:.3f} | {r:.3f}" for s, d, r in scores.values())
            + " | "
            + " | ".join(f"{change[site]:+.3f}" for site in args.sites)
            + f" | {judged} |"
        )
        print(rows[-1], flush=True)
    table = (
        f"Machine: {cpu_description()}. Fits with fit's default recipe, the same steps on each site for every "
        "base; held-out δ1 and REL; Δ against the recorded 0.8.1 row.\n\n"
        "| start | aims-lab steps | δ1 | REL | mosd-tabletop steps | δ1 | REL | Δ aims-lab δ1 | Δ mosd-tabletop δ1 | "
        "verdict |\n|---|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    bases = " ".join(str(b) for b in args.bases)
    report(table, args.markdown, "Fits from each kitchen base", f"python bench/fit_bases.py --bases {bases}")


if __name__ == "__main__":
    main()
