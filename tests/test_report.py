"""``rgb2cloud-lab report``: quality.md from a published model, a compared checkpoint and real frames."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from conftest import FLOAT32_METRICS, KINECT, REPO, SEVEN_SCENES, TUM_FRAME, evaluate_cli, run_cli
from PIL import Image

from contract.geometry import colours, point_cloud, xyz
from contract.spec import GeneratorSpec
from lab.experiments import config_diff, experiments_section
from lab.records import ScoreRecord, record_config
from lab.render import render_points
from lab.report import ReportInputs, _compared, _generator_words, build_report, colour_camera_of
from recordings.manifest import ManifestReader
from recordings.sevenscenes import SevenScenesReader
from trainer.config import complete_config, load_config
from trainer.evaluate import evaluate_frames, load_predictor

SHIPPED_CONFIG = REPO / "configs" / "rgb2cloud-7scenes-0.8.0.yaml"


def write_unseen_manifest(path: Path) -> Path:
    """The report's unseen scene: a one-row manifest reading the real TUM frame in place."""
    path.write_text(
        "rgb,depth,depth_scale,fx,fy,cx,cy\n"
        f"{TUM_FRAME / 'TUM_color.png'},{TUM_FRAME / 'TUM_depth.png'},5000,535.4,539.2,320.1,247.6\n"
    )
    return path


def refused(*args: str) -> str:
    """``rgb2cloud-lab ARGS`` that must fail: its output, to check the message."""
    result = subprocess.run([sys.executable, "-m", "lab", *args], cwd=REPO, capture_output=True, text=True)
    assert result.returncode != 0, f"rgb2cloud-lab {' '.join(args)} succeeded"
    return result.stdout + result.stderr


@pytest.mark.slow
def test_report_scores_every_row_and_keeps_dataset_pixels_local(registry, trained_checkpoint, tmp_path):
    out = tmp_path / "docs"
    unseen = write_unseen_manifest(tmp_path / "tum-fr3-office.csv")  # the unseen frame, read in place
    experiments = tmp_path / "experiments.yaml"
    experiments.write_text(yaml.safe_dump({"eager checkpoint": str(trained_checkpoint)}))
    run_cli(
        "report",
        str(registry / "tiny" / "0.1.0"),
        "--root",
        str(SEVEN_SCENES),
        "--unseen",
        str(unseen),
        "--experiments",
        str(experiments),
        "--train-frames",
        "0-3",
        "--test-frames",
        "850-851",
        "--out",
        str(out),
        package="lab",
    )
    text = (out / "quality.md").read_text()
    # The commands that reproduce it use the card's run folder and the model's own config file.
    run = json.loads((registry / "tiny" / "0.1.0" / "card.json").read_text())["training"]["config"]["train"]["out_dir"]
    assert "rgb2cloud train configs/tiny-0.1.0.yaml" in text and f"rgb2cloud evaluate {run}/checkpoints/best.pt" in text
    for row in ("tiny 0.1.0 (ONNX)", "eager checkpoint", "baseline: constant", "per-pixel train median", "paper (TUM"):
        assert row in text
    assert "non-commercial" in text and "850-851" in text
    # The ONNX export and the eager checkpoint it came from score the same.
    rows = json.loads((out / "quality" / "metrics.json").read_text())["rows"]
    published = next(v for k, v in rows.items() if "tiny" in k)
    assert abs(published["rel"] - rows["eager checkpoint"]["rel"]) < 1e-4
    assert published["images"] == 2
    # The scale diagnostic beside the published row, from the same predictions.
    ratio = published["median_scaled"]["ratio"]["mean"]
    assert published["median_scaled"]["images"] == 2 and ratio > 0
    assert f"per test image, the ground-truth median over the predicted one is {ratio:.3f}" in text
    # Compared rows are scored on the unseen scene too.
    assert "| eager checkpoint |" in text[text.index("## A room it never saw") : text.index("## Experiments")]
    experiments = text[text.index("## Experiments") : text.index("## Reproduce")]
    assert "| eager checkpoint (`" in experiments and "| (same training config) |" in experiments
    local = ("7scenes-samples.png", "7scenes-pointcloud.png", "unseen-sample.png", "unseen-pointcloud.png")
    for name in ("pc_rmse_curve.png", *(f"local/{n}" for n in local)):
        assert Image.open(out / "quality" / name).size[0] > 100
    # Nothing with dataset pixels lands outside the ignored folder.
    assert {p.name for p in (out / "quality").glob("*.png")} == {"pc_rmse_curve.png"}

    # The compared checkpoint's scores are stored, so a report without runs/ can still show its row.
    stored = out / "quality" / "compared" / "eager-checkpoint.json"
    record = json.loads(stored.read_text())
    assert record["source"] == str(trained_checkpoint) and len(record["pc_rmse"]) == 2
    again = tmp_path / "again"
    inputs = ReportInputs(
        registry / "tiny" / "0.1.0",
        SEVEN_SCENES,
        unseen,
        {"stored": stored},
        again,
        train_frames="0-3",
        test_frames="850-851",
    )
    text = build_report(inputs).read_text()
    rows_again = json.loads((again / "quality" / "metrics.json").read_text())["rows"]
    assert rows_again["stored"] == rows["eager checkpoint"]
    assert f"| stored ([record]({os.path.relpath(stored, again)})) | (same training config) |" in text
    assert "are kept (2 in all)" in text  # the stored per-image scores still make a curve
    # A score made on other frames is refused, not shown beside this split's rows.
    with pytest.raises(ValueError, match="scored on"):
        build_report(dataclasses.replace(inputs, test_frames="850-850"))


@pytest.mark.slow
def test_a_run_scored_elsewhere_is_stored_as_the_record_the_report_would_make(trained_checkpoint, tmp_path):
    """``rgb2cloud record`` from ``evaluate``'s two outputs equals the report scoring the checkpoint itself."""
    unseen = write_unseen_manifest(tmp_path / "tum-fr3-office.csv")
    evaluate_cli(trained_checkpoint, tmp_path / "test", "850-851")
    # The unseen frame is scored through a copy of the manifest, as on another machine.
    elsewhere = tmp_path / "elsewhere.csv"
    elsewhere.write_text(unseen.read_text())
    run_cli(
        "evaluate", str(trained_checkpoint), "--format", "csv", "--root", str(elsewhere), "--out", str(tmp_path / "tum")
    )
    config = trained_checkpoint.parents[2] / "config.yaml"
    record_args = [
        "--test",
        str(tmp_path / "test" / "metrics.json"),
        "--unseen",
        str(tmp_path / "tum" / "metrics.json"),
    ]
    record_args += ["--unseen-manifest", str(unseen), "--config", str(config), "-s", "train.steps=6"]
    record_args += ["-s", "generator.work_scale=2", "--source", "a tiny run", "--out", str(tmp_path / "compared")]
    run_cli("record", "Scored elsewhere", *record_args, package="lab")
    stored = tmp_path / "compared" / "scored-elsewhere.json"

    inputs = ReportInputs(trained_checkpoint, SEVEN_SCENES, unseen, {}, tmp_path / "docs", test_frames="850-851")
    test, manifest = SevenScenesReader(SEVEN_SCENES, "850-851"), ManifestReader(unseen)
    direct = _compared("direct", trained_checkpoint, test, manifest, inputs)
    via_record = _compared("stored", stored, test, manifest, inputs)
    for field in ("split", "min_m", "max_m", "unseen"):
        assert getattr(via_record, field) == getattr(direct, field), field
    for field in ("test", "unseen_metrics", "pc_rmse"):
        assert getattr(via_record, field) == pytest.approx(getattr(direct, field), **FLOAT32_METRICS), field
    assert via_record.config == direct.config and via_record.source == "a tiny run"
    # Two evaluations under different depth ranges cannot make one record.
    run_cli(
        "evaluate",
        str(trained_checkpoint),
        "--format",
        "csv",
        "--root",
        str(elsewhere),
        "--out",
        str(tmp_path / "far"),
        "--max-depth",
        "5",
    )
    far = [*record_args[:2], "--unseen", str(tmp_path / "far" / "metrics.json"), *record_args[4:]]
    assert "unseen on [0.1, 5.0] m" in refused("record", "x", *far)
    # Nor can an evaluation of one frame stand for a manifest of two.
    two = tmp_path / "two.csv"
    two.write_text(unseen.read_text() + unseen.read_text().splitlines()[1] + "\n")
    other = [arg if arg != str(unseen) else str(two) for arg in record_args]
    assert "scored 1 frame(s)" in refused("record", "x", *other)


@pytest.mark.slow
def test_a_run_trained_on_registered_depth_is_scored_through_its_colour_camera(trained_checkpoint, tmp_path):
    """The report scores such a checkpoint as ``evaluate --colour-camera`` does, and others pixel to pixel."""
    camera = "{fx: 530, fy: 530, cx: 314.5, cy: 239, baseline_m: 0.009}"
    state = torch.load(trained_checkpoint, weights_only=True)
    state["config"]["data"]["train"][0]["colour_camera"] = yaml.safe_load(camera)
    registered = tmp_path / "registered" / "checkpoints" / "last.pt"
    registered.parent.mkdir(parents=True)
    torch.save(state, registered)
    unseen = write_unseen_manifest(tmp_path / "tum-fr3-office.csv")
    inputs = ReportInputs(registered, SEVEN_SCENES, unseen, {}, tmp_path / "docs", test_frames="850-851")
    test, manifest = SevenScenesReader(SEVEN_SCENES, "850-851"), ManifestReader(unseen)
    through = _compared("registered", registered, test, manifest, inputs)
    raw = _compared("raw", trained_checkpoint, test, manifest, inputs)

    args = ["--format", "7scenes", "--root", str(SEVEN_SCENES), "--frames", "850-851"]
    run_cli("evaluate", str(registered), *args, "--out", str(tmp_path / "e"), "--colour-camera", camera)
    evaluated = json.loads((tmp_path / "e" / "metrics.json").read_text())["metrics"]
    assert through.test == pytest.approx(evaluated, **FLOAT32_METRICS)
    # Same weights, read another way: the pixel-to-pixel row differs; the unseen TUM frame is registered
    # already, so it is read pixel to pixel (each model at its own camera: the registered run's is the colour one).
    assert through.test["rel"] != pytest.approx(raw.test["rel"])
    pixel_to_pixel, _, _ = evaluate_frames(load_predictor(registered), manifest, min_m=0.1, max_m=10.0)
    assert through.unseen_metrics == pytest.approx(pixel_to_pixel, **FLOAT32_METRICS)
    assert colour_camera_of(through.config, SEVEN_SCENES).fx == 530.0
    assert colour_camera_of(raw.config, SEVEN_SCENES) is None
    assert colour_camera_of(through.config, SEVEN_SCENES).flow() == camera


def test_the_generator_line_names_every_option_that_changes_the_output():
    plain = GeneratorSpec(ngf=16, n_downsample=3, n_blocks=2, work_scale=2)
    assert _generator_words(plain) == "16 filters, 3 downsamplings, 2 residual blocks, working scale 1/2 of the input"
    assert _generator_words(plain.model_copy(update={"dilations": [1, 1]})) == _generator_words(plain)
    assert _generator_words(plain.model_copy(update={"dilations": [1, 4]})) == (
        "16 filters, 3 downsamplings, 2 residual blocks (first convolutions dilated 1, 4), "
        "working scale 1/2 of the input"
    )


def test_an_experiment_with_a_retired_option_still_says_what_it_changed():
    """Records are history: a run that turned on an option since retired still reads, the option named."""
    base = complete_config(load_config(SHIPPED_CONFIG).model_dump(mode="json"))
    old = json.loads(json.dumps(base))
    old["optim"]["ema"] = 0.999  # as a weight-average run of the time stored it
    old["generator"]["skips"] = False
    old["loss"]["l1_depth"] = 300.0
    assert record_config(old) == ({**base, "loss": {**base["loss"], "l1_depth": 300.0}}, {"optim.ema": 0.999})
    metrics = {"rel": 0.12, "delta1": 0.9}
    record = ScoreRecord(
        source="runs/x",
        config=old,
        split="s",
        min_m=0.1,
        max_m=10,
        unseen="u",
        test=metrics,
        unseen_metrics=metrics,
        scored="then",
    )
    lines = experiments_section(base, {"weight average": record}, {"weight average": Path("quality/compared/x.json")})
    assert (
        "| weight average ([record](quality/compared/x.json)) | `optim.ema`: 0.999 (retired); "
        "`loss.l1_depth`: 100.0 → 300.0 | 0.120 | 0.900 |"
    ) in lines


def test_config_diff_names_changed_leaves():
    base = {"loss": {"l1_depth": 100.0, "gan_mode": "lsgan"}, "train": {"out_dir": "a", "steps": 10}}
    other = {"loss": {"l1_depth": 0.0, "gan_mode": "lsgan"}, "train": {"out_dir": "b", "steps": 10}}
    assert config_diff(base, other) == ["`loss.l1_depth`: 100.0 → 0.0"]


def test_a_key_added_since_an_older_run_reads_as_its_default():
    today = load_config(SHIPPED_CONFIG).model_dump(mode="json")
    older = json.loads(json.dumps(today))
    del older["inference"]  # saved before the section existed
    older["generator"]["dropout"] = 0.0
    assert config_diff(complete_config(today), complete_config(older)) == [
        "`generator.dropout`: 0.5 → 0.0",
        "`inference.median_radius`: 2 → 0",
        "`inference.median_sigma`: 0.2 → 0.1",
        "`inference.median_spacing`: 4 → 1",
    ]


def test_render_turns_about_the_centre_and_nearest_point_wins():
    depth = np.full((48, 64), 2.0, dtype=np.float32)
    rgb = np.zeros((48, 64, 3), dtype=np.uint8)
    rgb[..., 0] = 200
    intrinsics = KINECT.resized(64, 48)
    cloud = point_cloud(depth, rgb, intrinsics)
    points = xyz(cloud)
    front = render_points(points, colours(cloud), np.median(points, axis=0), yaw_deg=0, pitch_deg=0, size=(60, 80))
    assert (front[..., 0] == 200).any() and (front == 255).all(axis=-1).any()  # the plane and background
    # A nearer blue point in front of the plane hides it at its pixel.
    near = np.array([[0.0, 0.0, 1.0]], dtype=np.float32)
    image = render_points(
        np.concatenate([points, near]),
        np.concatenate([colours(cloud), [[0, 0, 255]]]).astype(np.uint8),
        np.zeros(3),
        yaw_deg=0,
        pitch_deg=0,
        size=(60, 80),
    )
    assert tuple(image[30, 40]) == (0, 0, 255)
