"""``docs/quality.md`` and its figures, from one command: every number in it is computed here.

    rgb2cloud-lab report weights/rgb2cloud-7scenes/0.8.0 \\
        --root ../shared/data/7scenes-redkitchen --unseen runs/tum-fr3-office.csv \\
        --experiments docs/quality/experiments.yaml

The published model is scored the way the service runs it (ONNX Runtime, after
its sha256 check). Each compared model (``--experiments``) (a checkpoint or a version folder)
is scored on the same test frames, and its training config is shown as a diff
against the published model's, so an experiment's row says exactly what changed.
Each one scored is also stored (``lab.records``), so that a later report on a
fresh clone, without ``runs/``, can compare it from the record.

Figures that contain dataset pixels (RGB, ground-truth depth, or clouds made
from them) go to ``quality/local/``, which git ignores: data under
``../shared/data`` is read in place and never copied into the repository.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from contract.card import PAPER_METRICS, ModelCard, load_card
from contract.errors import UserError
from contract.geometry import ColourCamera
from contract.spec import GeneratorSpec
from lab.diagnostics import MedianScaled
from lab.experiments import experiments_section
from lab.records import ScoreRecord, is_record, now, read_record, record_path, write_record
from lab.render import render_pair
from recordings.manifest import ManifestReader
from recordings.sevenscenes import SevenScenesReader
from trainer.baselines import fit_baselines, score_baselines
from trainer.config import complete_config, load_config
from trainer.evaluate import PAPER_TUM, FramePredict, beats, evaluate_frames, load_predictor, markdown_table
from trainer.visualize import plot_pc_curve, sample_grid

#: The paper's mean point-cloud RMSE on NYU (on TUM it is PAPER_TUM["pc_rmse_mean"]).
PAPER_NYU_PC_RMSE = 0.585
TUM_LICENCE = "TUM RGB-D (CC BY 4.0), via the Open3D test data (MIT)"


@dataclass
class ReportInputs:
    model: Path
    root: Path
    unseen: Path
    compare: dict[str, Path]
    out: Path
    #: The config that trains the published model (``rgb2cloud train``), named in the Reproduce section.
    config: Path | None = None
    #: The file ``compare`` was read from, named in the Reproduce section.
    experiments: Path | None = None
    train_frames: str = "0-799"
    test_frames: str = "850-999"
    min_m: float = 0.1
    max_m: float = 10.0


def training_config(path: Path) -> dict:
    """The complete run config a checkpoint or a published version was trained with.

    A version's inference settings are the ones in its graph, so that how it runs shows in
    the experiments table beside how it was trained.
    """
    if path.is_dir():
        card = load_card(path)
        spec, inference = card.generator.model_dump(mode="json"), card.inference.model_dump(mode="json")
        return complete_config({**card.training.config, "generator": spec, "inference": inference})
    from trainer.checkpoint import load_checkpoint

    return complete_config(load_checkpoint(path).config)


def colour_camera_of(config: dict, root: Path) -> ColourCamera | None:
    """The colour camera a run registered the sequence ``root``'s depth to, or None if it trained on raw depth.

    Such a model predicts the photo's view, so it is scored on that sequence's frames
    through the same camera pair (``evaluate --colour-camera``); others pixel to pixel.
    """
    cameras = {
        json.dumps(s["colour_camera"], sort_keys=True)
        for s in config["data"]["train"]
        if s["format"] == "7scenes" and Path(s["root"]).name == root.name and s.get("colour_camera")
    }
    if len(cameras) > 1:
        raise UserError(f"the run registered {root.name} to {len(cameras)} different colour cameras")
    return ColourCamera.model_validate(json.loads(cameras.pop())) if cameras else None


def _score(
    predict: FramePredict,
    frames,
    inputs: ReportInputs,
    samples: int = 0,
    scaled: bool = False,
    colour: ColourCamera | None = None,
):
    return evaluate_frames(
        predict,
        frames,
        min_m=inputs.min_m,
        max_m=inputs.max_m,
        samples=samples,
        progress=True,
        colour_camera=colour,
        diagnostics=[MedianScaled(inputs.min_m, inputs.max_m)] if scaled else [],
    )


def _compared(
    name: str, path: Path, test: SevenScenesReader, unseen: ManifestReader, inputs: ReportInputs
) -> ScoreRecord:
    """A compared model's scores: read from a stored record, or scored now and stored for next time."""
    split = f"{inputs.root.name} {inputs.test_frames}"
    if is_record(path):
        return read_record(path, split, inputs.min_m, inputs.max_m, str(inputs.unseen))
    predict = load_predictor(path)
    config = training_config(path)
    result, images, _ = _score(predict, test, inputs, colour=colour_camera_of(config, inputs.root))
    record = ScoreRecord(
        source=str(path),
        config=config,
        split=split,
        min_m=inputs.min_m,
        max_m=inputs.max_m,
        unseen=str(inputs.unseen),
        test=result,
        unseen_metrics=_score(predict, unseen, inputs)[0],
        pc_rmse=[r["pc_rmse"] for r in images],
        scored=f"scored {now()} by rgb2cloud-lab report",
    )
    write_record(record_path(inputs.out / "quality" / "compared", name), record)
    return record


def _scale_paragraph(result: dict) -> str:
    """Where the published model's error is: one distance per view, or the shape within it."""
    scaled = result["median_scaled"]
    ratio = scaled["ratio"]
    return (
        "Where the error is (a diagnostic, not the paper's protocol): per test image, the ground-truth median "
        f"over the predicted one is {ratio['mean']:.3f} ± {ratio['std']:.3f} (1 = the right distance). "
        f"Scaling each prediction by its own ratio would give REL {scaled['rel']:.3f}, δ1 {scaled['delta1']:.3f}, "
        f"log10 {scaled['log10']:.3f}: the gap to the row above is the part of the error that one wrong distance "
        "per view explains, and the rest is the shape within the view "
        "(`rgb2cloud-lab diagnose` prints this for any model and frames)."
    )


def _paper_line(result: dict) -> str:
    won = beats(result, PAPER_TUM)
    better = [k for k in PAPER_METRICS if won[k]]
    # Four decimals where it falls short: a miss can round to the paper's own three-decimal figure.
    worse = [f"{k}: {result[k]:.4f} against {PAPER_TUM[k]}" for k in PAPER_METRICS if not won[k]]
    return f"**better than the paper on {len(better)} of 6 metrics**" + (
        f" (not on {'; '.join(worse)})" if worse else ""
    )


def _generator_words(g: GeneratorSpec) -> str:
    """The card's generator in words, with every option beyond the paper that changes its output."""
    parts = [f"{g.ngf} filters", f"{g.n_downsample} downsamplings", f"{g.n_blocks} residual blocks"]
    if g.dilations and max(g.dilations) > 1:
        parts[-1] += f" (first convolutions dilated {', '.join(map(str, g.dilations))})"
    parts.append(f"working scale 1/{g.work_scale} of the input")
    return ", ".join(parts)


def _card_section(card: ModelCard, model_dir: Path) -> list[str]:
    size_mb = sum((model_dir / f).stat().st_size for f in card.files) / 1e6
    data = "; ".join(f"{d.name} ({d.licence})" for d in card.training.data)
    inference = card.inference.describe() or "none"
    return [
        f"- **Model**: `{card.name}` {card.version}, `{model_dir}`; files {', '.join(card.files)}: "
        f"{size_mb:.1f} MB in all.",
        f"- **Generator**: pix2pixHD global generator, {_generator_words(card.generator)}.",
        f"- **Inference settings** (in the exported graph): {inference}.",
        *([f"- **Weights**: {card.derived_from}'s."] if card.derived_from else []),
        f"- **Trained on**: {data}. {card.training.steps} steps, {card.training.duration_s / 60:.0f} min of "
        f"training on {card.training.hardware}.",
        "- **Licence**: the weights were trained on Microsoft 7-Scenes, whose licence allows **non-commercial "
        "research use only**; the model inherits that restriction. Do not use it commercially.",
    ]


def build_report(inputs: ReportInputs) -> Path:
    """Score everything, write the figures and ``quality.md``; returns the Markdown path."""
    out = Path(inputs.out)
    figures, local = out / "quality", out / "quality" / "local"
    local.mkdir(parents=True, exist_ok=True)
    card = load_card(inputs.model)
    predict = load_predictor(inputs.model)
    label = predict.label
    test = SevenScenesReader(inputs.root, inputs.test_frames)
    base_config = training_config(inputs.model)
    colour = colour_camera_of(base_config, inputs.root)

    ours, per_image, grid = _score(predict, test, inputs, samples=4, scaled=True, colour=colour)
    rows = {f"**{label}**": ours}
    curves = {label: [r["pc_rmse"] for r in per_image]}
    unseen = ManifestReader(inputs.unseen)
    records = {name: _compared(name, path, test, unseen, inputs) for name, path in inputs.compare.items()}
    for name, record in records.items():
        rows[name] = record.test
        if record.pc_rmse is not None:
            curves[name] = record.pc_rmse

    fitted = fit_baselines(SevenScenesReader(inputs.root, inputs.train_frames))
    baselines = score_baselines(fitted, test, inputs.min_m, inputs.max_m)
    rows[f"baseline: constant {fitted['constant']:.2f} m (train median)"] = baselines["constant"]
    rows["baseline: per-pixel train median"] = baselines["per_pixel"]
    rows["paper (TUM, Table 2)"] = PAPER_TUM

    plot_pc_curve(curves, figures / "pc_rmse_curve.png")
    sample_grid(grid).save(local / "7scenes-samples.png")
    middle = test[len(test) // 2]
    photo_camera = colour.intrinsics(*middle.depth.shape[::-1]) if colour else middle.intrinsics
    render_pair(predict(middle.rgb, photo_camera), middle, colour).save(local / "7scenes-pointcloud.png")
    unseen_result, _, unseen_grid = _score(predict, unseen, inputs, samples=1, scaled=True)
    sample_grid(unseen_grid).save(local / "unseen-sample.png")
    render_pair(unseen_grid[0][1], unseen[0]).save(local / "unseen-pointcloud.png")
    split = f"{inputs.root.name} {inputs.test_frames}"
    metrics = {"split": split, "rows": rows, "unseen": unseen_result, "per_image": per_image}
    (figures / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")

    links = {name: Path(os.path.relpath(path, out)) for name, path in inputs.compare.items()}
    lines = [
        "# Quality of the bundled default model",
        "",
        "Generated by `rgb2cloud-lab report` (command at the end); every number below is computed by it, "
        "or read from a stored record that an earlier run of it computed from the checkpoint the record names.",
        "",
        *_card_section(card, inputs.model),
        "",
        *_test_section(inputs, rows, ours, len(curves), colour),
        *_unseen_section(inputs, label, unseen_result, records, len(unseen)),
        *experiments_section(base_config, records, links),
        "## Reproduce",
        "",
        *_reproduce(inputs, card, colour, unseen),
    ]
    path = out / "quality.md"
    path.write_text("\n".join(lines))
    return path


def _test_section(
    inputs: ReportInputs, rows: dict[str, dict], ours: dict, curves: int, colour: ColourCamera | None
) -> list[str]:
    """The test split's table, what it says, the point-cloud curve and where the samples are."""
    return [
        f"## 7-Scenes RedKitchen test split: frames {inputs.test_frames}",
        "",
        f"Never seen in training or model selection (train split {inputs.train_frames}). Full 640x480, ground "
        f"truth valid in [{inputs.min_m}, {inputs.max_m}] m, metrics per image then averaged, no median scaling. "
        "The published model runs through ONNX Runtime, as the service runs it."
        + (
            " It was trained on depth registered to the colour camera, so it predicts the photo's view; each "
            "valid ground-truth pixel (the depth camera's) is compared with the prediction at the colour pixel "
            "that sees the same point (`rgb2cloud evaluate --colour-camera`, camera fitted on train frames by "
            "`rgb2cloud calibrate`)."
            if colour
            else ""
        ),
        "",
        markdown_table(rows),
        "",
        f"The published model is {_paper_line(ours)}.",
        "",
        _scale_paragraph(ours),
        "",
        "The two baselines use no image at all: they show what knowing the room is worth. "
        "RMSE alone says little in a small room; δ1 and REL say more.",
        "",
        "## Point-cloud RMSE",
        "",
        f"Mean per-image point-cloud RMSE (formula (5) on both depths, same pixels): "
        f"**{ours['pc_rmse_mean']:.3f} m** on this split; the paper reports {PAPER_TUM['pc_rmse_mean']} m on TUM and "
        f"{PAPER_NYU_PC_RMSE} m on NYU. The Figure-8-style curve (fraction of test images with RMSE below r), "
        f"for the published model and each compared run whose per-image scores are kept ({curves} in all):",
        "",
        "![point-cloud RMSE curve](quality/pc_rmse_curve.png)",
        "",
        "## Samples",
        "",
        "The command writes, into `quality/local/`: `7scenes-samples.png` (RGB | predicted | ground truth for "
        "four test frames), `7scenes-pointcloud.png` (a predicted point cloud beside the ground-truth one, "
        "from a virtual camera turned 35°), and `unseen-sample.png` and `unseen-pointcloud.png` (the same for "
        "the unseen scene below). They hold dataset pixels, so they stay on your machine.",
        "",
    ]


def _unseen_section(
    inputs: ReportInputs, label: str, result: dict, records: dict[str, ScoreRecord], frames: int
) -> list[str]:
    """The published model and every compared run on a room none of them saw."""
    return [
        "## A room it never saw",
        "",
        f"`{inputs.unseen}` ({frames} frame(s); ours is the real TUM fr3 office frame, {TUM_LICENCE}), "
        "with its own camera's intrinsics:",
        "",
        markdown_table(
            {
                f"**{label}**": result,
                **{name: record.unseen_metrics for name, record in records.items()},
                "paper (TUM, Table 2; trained on TUM)": PAPER_TUM,
            }
        ),
        "",
        f"The median of truth / prediction is {result['median_scaled']['ratio']['mean']:.2f}; scaled by "
        f"it, REL would be {result['median_scaled']['rel']:.3f}. A model trained on one kitchen has learnt "
        "that kitchen: in another room, with another camera, its absolute scale and layout do not carry over. "
        "Train a model of your own space on some of your own RGB-D frames ([training.md](training.md)).",
        "",
    ]


def _reproduce(inputs: ReportInputs, card: ModelCard, colour: ColourCamera | None, unseen: ManifestReader) -> list:
    """The commands that train, score and publish the model, then rebuild this report."""
    config = inputs.config or Path("configs") / f"{card.name}-{card.version}.yaml"
    trained = load_config(config).model_dump(mode="json") if config.is_file() else card.training.config
    run = trained["train"]["out_dir"]
    checkpoint = f"{run}/checkpoints/{'best' if trained['data']['val'] else 'last'}.pt"
    camera = f" --colour-camera '{colour.flow()}'" if colour else ""
    parity = os.path.normpath(unseen.pairs[0].rgb)
    compare = f" --experiments {inputs.experiments}" if inputs.experiments else ""
    return [
        "```sh",
        f"rgb2cloud train {config}",
        f"rgb2cloud evaluate {checkpoint} --format 7scenes --root {inputs.root} --frames {inputs.test_frames} "
        f"--out {run}/eval-test{camera}",
        f"rgb2cloud evaluate {checkpoint} --format csv --root {inputs.unseen} --out {run}/eval-unseen",
        f"rgb2cloud export {checkpoint} --name {card.name} --version {card.version} "
        f"--metrics {run}/eval-test/metrics.json --metrics {run}/eval-unseen/metrics.json --parity-image {parity} "
        f"--registry {Path(run).parent}/weights",
        f"rgb2cloud baselines --format 7scenes --root {inputs.root} --train-frames {inputs.train_frames} "
        f"--test-frames {inputs.test_frames}",
        f"rgb2cloud-lab report {inputs.model} --root {inputs.root} --unseen {inputs.unseen}{compare} "
        f"--out {inputs.out}",
        "```",
        "",
        "The config's `inference` section is what export bakes into the graph. The generator's CPU speed is "
        "measured by `bench/serving.py`; see [benchmarks.md](benchmarks.md).",
        "",
    ]
