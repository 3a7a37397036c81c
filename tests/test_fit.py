"""``rgb2cloud fit``: real frames written in the layouts people record, fitted end to end on a small budget."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import torch
from conftest import REPO, run_cli
from PIL import Image

from contract.card import load_card
from contract.runtime import OnnxGenerator
from harness.service import ServedDepth, running_service
from recordings.folders import CameraFile, find_pairs, read_intrinsics_json
from recordings.formats import ReadOptions, detect_format, open_recording
from trainer.checkpoint import load_generator_weights
from trainer.config import DataSource
from trainer.data.sources import open_source
from trainer.evaluate import evaluate_frames, load_predictor
from trainer.fit.budget import Plan, Workload, plan_training
from trainer.fit.split import split_recording
from trainer.inference import EagerGenerator, InferenceGraph
from trainer.networks import GlobalGenerator

MOSD = REPO.parent / "shared" / "data" / "mosd-tabletop"
#: Frames are written at a quarter of their size, so a fit of a tiny model takes seconds a step.
SCALE = 0.25
#: How far past its budget a fit may end: the plan's estimates for scoring and export are
#: measured on the bundled model's size, and process start-up and imports come on top.
BUDGET_MARGIN_S = 30.0


def write_recording(
    root: Path, count: int, *, open3d: bool = True, timestamps: bool = False, depth_scale: float = 1000.0
) -> Path:
    """``count`` real mOSD frames in the folders layout, with intrinsics.json in one of its two forms."""
    (root / "color").mkdir(parents=True)
    (root / "depth").mkdir()
    names = sorted(p.stem for p in (MOSD / "color").glob("learn*.jpg"))[:count]
    for i, name in enumerate(names):
        rgb = Image.open(MOSD / "color" / f"{name}.jpg").convert("RGB")
        depth = Image.open(MOSD / "depth" / f"{name}.png")
        size = (round(rgb.width * SCALE), round(rgb.height * SCALE))
        colour_stem = f"{1000 + i / 30:.6f}" if timestamps else str(i)
        depth_stem = f"{1000 + i / 30 + 0.004:.6f}" if timestamps else str(i)  # the streams are not in step
        rgb.resize(size, Image.Resampling.BILINEAR).save(root / "color" / f"{colour_stem}.jpg")
        raw = np.asarray(depth.resize(size, Image.Resampling.NEAREST), dtype=np.float64) * depth_scale / 1000.0
        Image.fromarray(np.clip(raw, 0, 65535).astype(np.uint16)).save(root / "depth" / f"{depth_stem}.png")
    f, c = 525.0 * SCALE, (319.5 + 0.5) * SCALE - 0.5
    if open3d:
        matrix = [f, 0, 0, 0, f, 0, c, (239.5 + 0.5) * SCALE - 0.5, 1]
        intrinsics = {"width": size[0], "height": size[1], "intrinsic_matrix": matrix, "depth_scale": depth_scale}
    else:
        intrinsics = {"fx": f, "fy": f, "cx": c, "cy": (239.5 + 0.5) * SCALE - 0.5, "depth_scale": depth_scale}
    (root / "intrinsics.json").write_text(json.dumps(intrinsics))
    return root


def fit_args(data: Path, tmp: Path, start: Path, budget: str = "1") -> list[str]:
    return [
        "fit",
        str(data),
        "--name",
        "my-room",
        "--licence",
        "mOSD (research use), test copy",
        "--budget",
        budget,
        "--from",
        str(start),
        "--registry",
        str(tmp / "registry"),
        "--out",
        str(tmp / "run"),
        "--register",
        "no",
    ]


def refused(*args: str) -> str:
    """``rgb2cloud ARGS`` that must fail with one error line (after the progress bar, on a terminal in place)."""
    result = subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, capture_output=True, text=True)
    last = result.stderr.strip().splitlines()[-1]
    assert result.returncode == 1 and last.startswith("error: "), result.stderr
    assert "Traceback" not in result.stderr
    return last


@pytest.mark.slow
def test_fit_end_to_end_publishes_a_model_the_service_serves(registry, tmp_path, monkeypatch):
    data = write_recording(tmp_path / "rec", 24, open3d=True, timestamps=True)
    start = registry / "tiny" / "0.1.0"
    # No --registry: fit publishes into the user's data folder, never into the checkout's tracked weights/.
    monkeypatch.delenv("RGB2CLOUD_REGISTRY", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    args = fit_args(data, tmp_path, start)
    at = args.index("--registry")
    began = time.monotonic()
    result = run_cli(*args[:at], *args[at + 2 :], "--precision", "int8")
    stdout = result.stdout
    assert time.monotonic() - began < 60 + BUDGET_MARGIN_S  # the budget holds, the int8 graph's calibration in it
    # Not a terminal: no bar redrawn in place, but a line as each phase starts (and every 30 s), in order.
    phases = list(dict.fromkeys(line.split(":")[0] for line in result.stderr.splitlines() if "%|" in line))
    assert "\r" not in result.stderr
    assert phases == ["inspecting", "measuring", "training", "scoring", "publishing", "done"], result.stderr
    assert "pairs: 24 found, 0 skipped" in stdout and "split: train 16, selection 2" in stdout
    assert "| fitted model |" in stdout and "| tiny 0.1.0, zero-shot (the start) |" in stdout
    own = tmp_path / "data" / "rgb2cloud" / "models"
    folder = own / "my-room" / "0.1.0"
    assert (
        f"published {folder}" in stdout
        and f"run folder (config, checkpoints, split manifests): {tmp_path / 'run'}" in stdout
    )
    assert not (REPO / "weights" / "my-room").exists()
    card = load_card(folder)
    assert card.training.fit.start_from == str(start) and card.training.fit.budget_min == 1.0
    # The last checkpoint is published, none chosen on the selection frames (they draw the curves and samples).
    checkpoints = tmp_path / "run" / "train" / "checkpoints"
    assert not (checkpoints / "best.pt").exists() and (tmp_path / "run" / "train" / "samples").is_dir()
    assert card.training.steps == json.loads((tmp_path / "run" / "train" / "summary.json").read_text())["steps"]
    assert card.training.fit.fit_id == json.loads((tmp_path / "run" / "fit.json").read_text())["fit_id"]
    split = card.training.fit.split
    assert {part: split[part]["frames"] for part in split} == {"train": 16, "selection": 2, "gap": 1, "holdout": 5}
    assert split["holdout"]["last"] == f"{1000 + 23 / 30:.6f}"  # the end of the recording, in time order
    assert card.training.data[0].licence == "mOSD (research use), test copy"
    # The start's data, and its licences, come with its weights: tiny was trained on 7-Scenes.
    assert card.training.fit.start_model == "tiny 0.1.0"
    inherited = card.training.data[1:]
    assert inherited == [d.model_copy(update={"via": "tiny 0.1.0"}) for d in load_card(start).training.data]
    assert "non-commercial" in inherited[0].licence
    labels = [m.label for m in card.metrics]
    assert labels[0] is None and labels[1] == "tiny 0.1.0, zero-shot (the start)"
    assert labels[2].startswith("baseline: constant") and labels[3] == "baseline: per-pixel train median"
    assert all(m.images == 5 for m in card.metrics)
    assert card.generator == load_card(start).generator
    loss = card.training.config["loss"]
    assert (loss["gan"], loss["feature_matching"], loss["l1_depth"]) == (0, 0, 100)  # a fit's objective: the L1 alone
    assert card.int8 is not None and card.int8.file in card.files
    assert card.int8.frames_from == ["train.csv all"]  # calibrated on the run folder's train part
    optim = card.training.config["optim"]
    # And Adam set for a regression: fit's peak rate, unless the Pacer re-planned on a slow machine so that the decay
    # had to start at step 0, from a lower peak that keeps the rate reached (trainer.fit.budget.continued_decay).
    assert optim["beta1"] == 0.9 and (
        optim["lr"] == 0.0005 or (optim["decay_start"] == 0 and 0 < optim["lr"] < 0.0005)
    ), optim
    transform = card.training.config["data"]["transform"]
    assert (transform["extent"], transform["whole_share"]) == ([1.0, 1.0], 0.0)  # whole frames, whatever the start's
    # The exact commands to serve it, and the service does.
    assert f"RGB2CLOUD_REGISTRY={own} RGB2CLOUD_MODEL=my-room:0.1.0 make serve" in stdout
    assert "/depth?model=my-room:0.1.0" in stdout
    holdout = open_source(DataSource(format="csv", root=tmp_path / "run" / "holdout.csv"))
    frames = [holdout[i] for i in range(len(holdout))]
    # On ONNX Runtime, the engine the tables are scored with: under auto each load may pick its own by timing.
    with running_service(
        registry=str(own), bundled_registry=str(registry), model="my-room:0.1.0", engine="onnxruntime"
    ) as service:
        # One rescale rule: each model is scored at its own card camera, the start's zero-shot row included,
        # so fit's table, evaluate and the service (given the recording's focal length) agree.
        for row, version in zip(card.metrics[:2], (folder, start), strict=True):
            low, high = row.depth_range_m
            evaluated, _, _ = evaluate_frames(load_predictor(version), frames, min_m=low, max_m=high)
            served_depth = ServedDepth(service.url, f"{load_card(version).name}:0.1.0")
            served, _, _ = evaluate_frames(served_depth, frames, min_m=low, max_m=high)
            assert abs(evaluated["delta1"] - row.delta1) <= 0.001 and abs(evaluated["rel"] - row.rel) <= 0.001
            assert abs(served["delta1"] - row.delta1) <= 0.001 and abs(served["rel"] - row.rel) <= 0.002
        photo = next((data / "color").iterdir()).read_bytes()
        response = httpx.post(f"{service.url}/depth", files={"image": photo}, timeout=30)
        assert response.status_code == 200 and response.headers["x-model-version"] == "0.1.0"
        int8 = httpx.post(f"{service.url}/depth", files={"image": photo}, params={"precision": "int8"}, timeout=30)
        assert int8.status_code == 200 and int8.headers["x-precision"] == "int8"  # fit --precision int8 shipped one
        listed = httpx.get(f"{service.url}/v1/models", timeout=10).json()["models"][0]["versions"][0]["card"]
        assert [d["licence"] for d in listed["data"]] == [d.licence for d in card.training.data]
    assert json.loads((tmp_path / "run" / "fit.json").read_text())["start_from"] == str(start)
    # Where it fails: the published ONNX scored on each held-out view (their mean is the card's), the worst drawn.
    lab = subprocess.run(
        [sys.executable, "-m", "lab", "failures", str(tmp_path / "run"), "--worst", "2"],
        cwd=REPO, capture_output=True, text=True, check=True,
    )  # fmt: skip
    views = [line.split(" | ") for line in lab.stdout.splitlines() if line.startswith("| holdout/1000.")]
    assert len(views) == 5 and [float(v[1]) for v in views] == sorted(float(v[1]) for v in views)
    assert abs(np.mean([float(v[1]) for v in views]) - card.metrics[0].delta1) <= 0.001
    assert "by the sensor's depth: the 2 worst views, and the other 3" in lab.stdout
    drawn = Image.open(tmp_path / "run" / "failures" / "worst.jpg")
    height, width = frames[0].depth.shape
    assert drawn.size == (4 * width, 3 * height)  # photo, sensor, model, δ1 map; the two worst and the best


@pytest.mark.slow
def test_a_fit_from_imagenet_renders_views_into_its_budget(registry, tmp_path):
    """--from imagenet: ImageNet's Lite0 under a fresh U-Net decoder, the encoder frozen; views rendered before
    the plan, into the run folder, their settings on the card."""
    from trainer.efficientnet import imagenet_state

    data = write_recording(tmp_path / "rec", 24, open3d=False)
    args = fit_args(data, tmp_path, registry / "tiny" / "0.1.0")
    args[args.index("--from") + 1] = "imagenet"
    views = ["--set", "data.views.share=0.5", "--set", "data.views.per_frame=2"]
    result = run_cli(*args, "--steps", "4", *views)
    phases = list(dict.fromkeys(line.split(":")[0] for line in result.stderr.splitlines() if "%|" in line))
    assert phases[:3] == ["inspecting", "rendering views", "measuring"], result.stderr
    assert "rendered views: 32, 2 of each of the 16 train frames, in" in result.stdout
    assert "50% of each batch" in result.stdout
    bank = tmp_path / "run" / "train" / "views"
    assert len(list(bank.glob("*.color.png"))) == 32 and len(list(bank.glob("*.depth.png"))) == 32
    card = load_card(tmp_path / "registry" / "my-room" / "0.1.0")
    assert card.training.fit.start_from == "imagenet" and card.training.fit.start_model is None
    assert card.generator.encoder == "efficientnet-lite0"
    config = card.training.config
    assert config["optim"]["encoder_lr_scale"] == 0 and config["data"]["views"]["share"] == 0.5
    assert config["data"]["views"]["forward"] == 0.45  # the card records every rendering setting
    # The encoder's lineage alone: nothing of the bundled kitchen model, nor its 7-Scenes licence.
    assert [d.name.startswith("ImageNet ILSVRC-2012") for d in card.training.data] == [False, True]
    # Frozen: the published encoder is ImageNet's, weights and BatchNorm statistics.
    weights = load_generator_weights(tmp_path / "registry" / "my-room" / "0.1.0", card.generator)
    imagenet = imagenet_state()
    for key in ("_conv_stem.weight", "_blocks.15._bn2.running_var"):
        assert torch.equal(weights[f"encoder.{key}"], imagenet[key])


def test_from_names_a_folder_a_registry_model_or_imagenet_and_defaults_to_the_bundled_base(registry, tmp_path):
    from contract.errors import UserError
    from contract.registries import Registries
    from trainer.fit.start import resolve_start

    registries = Registries(tmp_path / "own", registry)
    assert resolve_start("imagenet", registries) is None
    with pytest.raises(UserError, match="no bundled rgb2cloud-7scenes to start from"):
        resolve_start(None, registries)  # the default: this bundled registry holds only tiny
    assert (
        resolve_start(None, Registries(tmp_path / "own", REPO / "weights")) == REPO / "weights/rgb2cloud-7scenes/0.9.1"
    )
    assert resolve_start(str(registry / "tiny" / "0.1.0"), registries) == registry / "tiny" / "0.1.0"
    assert resolve_start("tiny", registries) == registry / "tiny" / "0.1.0"
    assert resolve_start("tiny:0.1.0", registries) == registry / "tiny" / "0.1.0"
    for wrong in ("tiny:0.2.0", "nothing", "scratch"):
        with pytest.raises(UserError, match=f"--from {wrong}: no such version folder or model .*'imagenet'"):
            resolve_start(wrong, registries)


#: ``rgb2cloud ARGS`` whose process sends itself SIGINT (Ctrl-C) after the first training step that
#: follows its first checkpoint: the interruption lands mid-training on any machine, however fast or
#: loaded. The test fixes the plan with ``--steps 40`` (a checkpoint every 4, a tenth of the steps), so
#: the machine's speed cannot decide whether a checkpoint comes before the end.
CTRL_C_AFTER_FIRST_CHECKPOINT = """
import os, signal, sys
from pathlib import Path

import trainer.fit.workflow as workflow
from cli.main import main

last, *sys.argv[1:] = sys.argv[1:]
tick = workflow.Progress.tick
# Ctrl-C as a terminal delivers it, even where this process was started with SIGINT ignored (a
# background job of a non-interactive shell, as CI runners start them): Python then installs no
# handler of its own, and the signal would be dropped.
signal.signal(signal.SIGINT, signal.default_int_handler)


def tick_then_interrupt(self, *step):
    tick(self, *step)
    if step and Path(last).exists():
        os.kill(os.getpid(), signal.SIGINT)


workflow.Progress.tick = tick_then_interrupt
main()
"""


@pytest.mark.slow
def test_ctrl_c_before_the_first_checkpoint_is_continued_by_the_hint_it_prints(registry, tmp_path):
    """Ctrl-C after fit.json is written but before any checkpoint: the printed hint, followed, finishes the fit."""
    data = write_recording(tmp_path / "rec", 24, open3d=False)
    args = [*fit_args(data, tmp_path, registry / "tiny" / "0.1.0"), "--steps", "8"]
    # The first training step interrupts: fit.json exists by then, and no checkpoint does.
    command = [sys.executable, "-c", CTRL_C_AFTER_FIRST_CHECKPOINT, str(tmp_path / "run" / "fit.json"), *args]
    interrupted = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert interrupted.returncode == 130 and "Traceback" not in interrupted.stderr, interrupted.stderr
    assert not (tmp_path / "run" / "train" / "checkpoints" / "last.pt").exists()
    hint = interrupted.stderr.strip().splitlines()[-1]
    assert hint == "interrupted: the same command with --resume continues it"
    result = run_cli(*args, "--resume")
    assert "resuming before the first checkpoint: training all 8 steps from the start" in result.stdout
    assert load_card(tmp_path / "registry" / "my-room" / "0.1.0").training.steps == 8


@pytest.mark.slow
def test_pixels_sets_the_camera_a_model_trains_and_serves_at(registry, tmp_path):
    """``--pixels`` for live: a 160x120 recording fitted at 80x60 trains at that camera and its card names it,
    so the service resamples every photo to it; a size the generator cannot work at is one line."""
    data = write_recording(tmp_path / "rec", 24, open3d=False)
    args = [*fit_args(data, tmp_path, registry / "tiny" / "0.1.0"), "--steps", "2"]
    run_cli(*args, "--pixels", "80x60")
    card = load_card(tmp_path / "registry" / "my-room" / "0.1.0")
    recorded = read_intrinsics_json(data / "intrinsics.json")  # 160x120, fx 131.25, cx 79.5, cy 59.5
    assert (card.camera.width, card.camera.height) == (80, 60)
    # Halved about pixel centres: (79.5 + 0.5) / 2 - 0.5.
    assert card.camera.fx == pytest.approx(recorded.fx * 0.5) and (card.camera.cx, card.camera.cy) == (39.5, 29.5)
    data_config = card.training.config["data"]
    # tiny works at half its input (work_scale 2) in multiples of 4: 40x30 at the working scale, cropped to 40x28.
    assert data_config["val_scale"] == 0.5 and data_config["transform"]["size"] == [28, 40]
    assert data_config["transform"]["scale"] == pytest.approx([0.25, 0.275])
    # 8x6 is a twentieth of the recording a side: 4x3 at tiny's working scale (2x), 4x0 in its multiples of 4,
    # where it needs one multiple a side: 8 pixels a side at the model's camera.
    elsewhere = ("--out", str(tmp_path / "small"))
    small = refused(*fit_args(data, tmp_path, registry / "tiny" / "0.1.0"), *elsewhere, "--pixels", "8x6")
    assert "the model would see this 160x120 recording at 8x6 (--pixels 8x6)" in small
    assert small.endswith("its generator needs at least 8 pixels a side")
    wrong = subprocess.run(
        [sys.executable, "-m", "cli", *args, "--pixels", "320"], cwd=REPO, capture_output=True, text=True
    )
    assert wrong.returncode == 2 and "expected WIDTHxHEIGHT in pixels" in wrong.stderr


def test_ctrl_c_before_training_hints_a_fresh_start(tmp_path):
    from trainer.fit.state import interrupted_hint

    assert "without --resume" in interrupted_hint(tmp_path)
    (tmp_path / "fit.json").write_text("{}")
    assert "with --resume" in interrupted_hint(tmp_path)


@pytest.mark.slow
def test_an_interrupted_fit_resumes_where_it_stopped(registry, tmp_path):
    data = write_recording(tmp_path / "rec", 24, open3d=False)
    args = [*fit_args(data, tmp_path, registry / "tiny" / "0.1.0"), "--steps", "40", "--set", "loss.l1_depth=7"]
    last = tmp_path / "run" / "train" / "checkpoints" / "last.pt"
    command = [sys.executable, "-c", CTRL_C_AFTER_FIRST_CHECKPOINT, str(last), *args]
    interrupted = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300)
    stderr = interrupted.stderr
    assert interrupted.returncode == 130 and "--resume" in stderr and "Traceback" not in stderr, stderr
    assert "plan: 40 steps as given" in interrupted.stdout
    stopped_at = torch.load(last, weights_only=True)["step"]
    assert stopped_at == 4  # the first checkpoint; the interruption came at step 5 of 40
    assert "a fit is already there; add --resume" in refused(*args)
    result = run_cli(*args, "--resume")
    assert f"resuming at step {stopped_at} of" in result.stdout + result.stderr
    card = load_card(tmp_path / "registry" / "my-room" / "0.1.0")
    assert card.training.steps == 40 and card.training.config["loss"]["l1_depth"] == 7  # --set changed the recipe
    # Finished: resuming again publishes nothing and says what was published.
    message = refused(*args, "--resume")
    assert "this fit finished and published" in message and "my-room/0.1.0" in message
    # Also when Ctrl-C came between publishing and fit.json saying so: the card names the run.
    state_file = tmp_path / "run" / "fit.json"
    state = json.loads(state_file.read_text())
    state_file.write_text(json.dumps({**state, "published": None}))
    message = refused(*args, "--resume")
    assert "this fit finished and published" in message and "my-room/0.1.0" in message
    assert not (tmp_path / "registry" / "my-room" / "0.2.0").exists()
    assert not (tmp_path / "registry" / "my-room" / "0.2.0").exists()


def test_starting_from_a_published_version_reproduces_its_outputs_at_step_0(registry):
    version = registry / "tiny" / "0.1.0"
    card = load_card(version)
    generator = GlobalGenerator(card.generator)
    generator.load_state_dict(load_generator_weights(version, card.generator))
    eager = EagerGenerator(InferenceGraph(generator.eval(), card.inference), card.input_multiple)
    exported = OnnxGenerator(version / "generator.onnx", card.input_multiple)
    rgb = np.asarray(Image.open(next((MOSD / "color").iterdir())).convert("RGB"))
    np.testing.assert_allclose(eager.predict_raw(rgb), exported.predict_raw(rgb), atol=1e-4)
    other = card.generator.model_copy(update={"ngf": 16})
    with pytest.raises(ValueError, match="is not this run's"):
        load_generator_weights(version, other)


def test_layouts_are_detected_and_an_unknown_one_is_explained(tmp_path):
    assert detect_format(write_recording(tmp_path / "rec", 2)) == "folders"
    (tmp_path / "tum").mkdir()
    (tmp_path / "tum" / "rgb.txt").write_text("")
    (tmp_path / "tum" / "depth.txt").write_text("")
    assert detect_format(tmp_path / "tum") == "tum"
    assert detect_format(REPO.parent / "shared" / "data" / "7scenes-redkitchen") == "7scenes"
    (tmp_path / "m.csv").write_text("")
    assert detect_format(tmp_path / "m.csv") == "csv"
    (tmp_path / "odd").mkdir()
    (tmp_path / "odd" / "pictures").mkdir()
    (tmp_path / "odd" / "notes.txt").write_text("")
    message = refused("fit", str(tmp_path / "odd"), "--name", "x", "--licence", "y")
    assert "cannot tell its layout (found notes.txt, pictures/)" in message and "color/" in message
    (tmp_path / "photos-only" / "rgb").mkdir(parents=True)
    message = refused("fit", str(tmp_path / "photos-only"), "--name", "x", "--licence", "y")
    assert message.endswith(
        "photos-only: rgb/ but no depth/ folder: fit needs depth images (16-bit PNG) beside the photos"
    )
    message = refused("fit", str(tmp_path / "odd"), "--name", "rgb2cloud-7scenes", "--licence", "y")
    assert "--name rgb2cloud-7scenes: a bundled model has this name" in message


def test_pairs_match_by_name_or_by_nearest_timestamp(tmp_path):
    root = tmp_path / "rec"
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    for stem in ("10.000", "10.033", "10.066", "10.500"):
        (root / "rgb" / f"{stem}.png").write_bytes(b"")
    for stem in ("10.005", "10.031", "10.070", "11.000"):
        (root / "depth" / f"{stem}.png").write_bytes(b"")
    pairs, skipped = find_pairs(root)
    assert [(p.name, p.depth.stem) for p in pairs] == [("10.000", "10.005"), ("10.033", "10.031"), ("10.066", "10.070")]
    assert skipped == [("10.500", "no depth image with this name or within the time tolerance")]
    numbered = tmp_path / "numbered"
    (numbered / "image").mkdir(parents=True)
    (numbered / "depth").mkdir()
    for stem in ("2", "10", "1"):  # frame numbers: time order is numeric, not text
        (numbered / "image" / f"{stem}.jpg").write_bytes(b"")
        (numbered / "depth" / f"{stem}.png").write_bytes(b"")
    assert [p.name for p in find_pairs(numbered)[0]] == ["1", "2", "10"]


def test_both_intrinsics_forms_and_command_line_overrides(tmp_path):
    (tmp_path / "a.json").write_text(json.dumps({"intrinsic_matrix": [500, 0, 0, 0, 510, 0, 320, 240, 1]}))
    (tmp_path / "b.json").write_text(json.dumps({"fx": 500, "fy": 510, "cx": 320, "cy": 240, "depth_scale": 5000}))
    assert read_intrinsics_json(tmp_path / "a.json") == CameraFile(500, 510, 320, 240, None)
    assert read_intrinsics_json(tmp_path / "b.json") == CameraFile(500, 510, 320, 240, 5000)
    assert read_intrinsics_json(tmp_path / "b.json").merged(CameraFile(fx=600)).fx == 600
    (tmp_path / "c.json").write_text(json.dumps({"fx": 500}))
    with pytest.raises(ValueError, match="expected Open3D's intrinsic_matrix, or fx, fy, cx and cy"):
        read_intrinsics_json(tmp_path / "c.json")
    data = write_recording(tmp_path / "rec", 2)
    (data / "intrinsics.json").unlink()
    with pytest.raises(ValueError, match=r"no camera intrinsics .* pass --fx --fy --cx --cy"):
        open_recording(data, None, ReadOptions(), tmp_path)
    pairs = open_recording(data, None, ReadOptions(CameraFile(100, 100, 20, 15, 1000)), tmp_path).pairs
    assert (pairs[0].camera.fx, pairs[0].camera.cy, pairs[0].depth_scale) == (100, 15, 1000)


@pytest.mark.slow
def test_wrong_units_and_too_few_pairs_are_refused_with_what_to_do(tmp_path):
    metres_as_millimetres = write_recording(tmp_path / "mm", 24, depth_scale=1000.0)
    message = refused("fit", str(metres_as_millimetres), "--name", "x", "--licence", "y", "--depth-scale", "1")
    assert "the median depth is" in message and "likely --depth-scale 1000" in message
    few = write_recording(tmp_path / "few", 12)
    assert refused("fit", str(few), "--name", "x", "--licence", "y", "--register", "no") == (
        f"error: {few}: 12 usable pairs, fit needs at least 20 (record a little longer)"
    )


def test_the_split_is_time_ordered_with_a_gap_or_the_named_holdout(tmp_path):
    pairs = open_recording(write_recording(tmp_path / "rec", 40), None, ReadOptions(), tmp_path).pairs
    split = split_recording(pairs)
    assert (split.train[-1], split.selection, split.gap, split.holdout[0]) == (26, [27, 28, 29], [30, 31], 32)
    assert max(split.train + split.selection) < min(split.gap) < min(split.holdout)
    named = split_recording(pairs, holdout="30-39", gap_frames=0)
    assert named.holdout == list(range(30, 40)) and named.gap == [] and named.selection == [27, 28, 29]
    by_glob = split_recording(pairs, holdout="3?", gap_frames=2)
    assert by_glob.holdout == list(range(30, 40)) and by_glob.gap == [28, 29]
    with pytest.raises(ValueError, match=r"--holdout: frames .* match no frame name"):
        split_recording(pairs, holdout="test*")


def test_the_plan_spends_what_the_budget_leaves_and_refuses_a_budget_too_small():
    work = Workload(selection_frames=4, holdout_frames=10, predict_s=0.5, scores_start=True, median_taps=25)
    plan = plan_training(budget_s=600, spent_s=30, step_s=2.0, work=work)
    # 600 - 30 - tail (3 x 10 x 0.5 + 20 + 60 + 15 = 110) - validation (5 x 4 x 0.5 = 10) = 450 s: 225 steps.
    assert plan == Plan(
        budget_s=600,
        step_s=2.0,
        train_s=450,
        steps=225,
        decay_start=112,
        val_every=57,  # validations at 57, 114 and 171, and at the last step: the four planned
        checkpoint_every=22,
        deadline_s=490,
        validation_s=10,
    )
    # An int8 graph too: its calibration's 20 frames at 4 predictions each, and 20 s more: 60 s, 30 steps fewer.
    int8 = plan_training(budget_s=600, spent_s=30, step_s=2.0, work=dataclasses.replace(work, int8=True))
    assert (int8.train_s, int8.steps, int8.deadline_s) == (390, 195, 430)
    with pytest.raises(ValueError, match="leaves no time to train"):
        plan_training(budget_s=120, spent_s=30, step_s=2.0, work=work)
