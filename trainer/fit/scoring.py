"""The truth about a fit: the fitted model beside where it started and beside knowing nothing.

On the held-out frames, scored once: the fitted model; the model it started from,
zero-shot; and two baselines that never look at the photo (the train frames' median
depth everywhere, and each pixel's train median). A fit that does not beat the
baselines has learnt the room's average, not depth from the photo, and fit says so.
"""

from __future__ import annotations

from pathlib import Path

from contract.card import Metrics
from contract.geometry import ColourCamera
from trainer.baselines import fit_baselines, score_baselines
from trainer.config import DataSource, RunConfig
from trainer.data.sources import open_source
from trainer.evaluate import evaluate_frames, load_predictor, markdown_table


def score_holdout(
    checkpoint: Path, start: Path | None, config: RunConfig, holdout: DataSource, colour: ColourCamera | None
) -> tuple[str, list[Metrics], str | None]:
    """The held-out table, the card's metrics entries, and a warning when the fit loses to a baseline."""
    frames = open_source(holdout)
    depth_range = (config.data.eval_min_m, config.data.eval_max_m)
    split = f"held out: {len(frames)} frames"
    # Each model sees each photo at its own camera (the rule in contract.resample), as the service shows it.
    models = {"fitted model": load_predictor(checkpoint)}
    if start is not None:
        models[f"{start.parent.name} {start.name}, zero-shot (the start)"] = load_predictor(start)
    rows, metrics = {}, []
    for label, predict in models.items():
        result, _, _ = evaluate_frames(
            predict, frames, min_m=depth_range[0], max_m=depth_range[1], colour_camera=colour
        )
        rows[label] = result
        card_label = None if label == "fitted model" else label
        metrics.append(Metrics.from_result(result, split, depth_range, colour, card_label))
    train = open_source(config.data.train[0].model_copy(update={"colour_camera": None}))
    fitted = fit_baselines(train)
    baselines = score_baselines(fitted, frames, *depth_range)
    for key, label in (
        ("constant", f"baseline: constant {fitted['constant']:.2f} m (train median)"),
        ("per_pixel", "baseline: per-pixel train median"),
    ):
        rows[label] = baselines[key]
        metrics.append(Metrics.from_result(baselines[key], split, depth_range, label=label))
    how = "read at the colour camera" if colour else "pixel to pixel"
    table = (
        f"\nheld-out frames: {len(frames)}, ground truth in [{depth_range[0]}, {depth_range[1]}] m, {how}, "
        f"no median scaling\n\n{markdown_table(rows)}\n"
    )
    ours = rows["fitted model"]
    lost = [
        label
        for key, label in (("constant", "constant"), ("per_pixel", "per-pixel median"))
        if ours["delta1"] <= baselines[key]["delta1"] or ours["rel"] >= baselines[key]["rel"]
    ]
    warning = None
    if lost:
        warning = (
            f"WARNING: the fitted model does not beat the {' and the '.join(lost)} baseline on delta1 and REL: "
            "it has learnt little more than the room's average depth. Record more varied views, or fit longer."
        )
    return table, metrics, warning
