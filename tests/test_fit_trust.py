"""What makes a fit's numbers trustworthy beyond its readers: which version a fit published, options that
apply, the same inference pixel limit as the service, and a checkpoint that carries its own camera."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from conftest import SEVEN_SCENES, evaluate_cli
from PIL import Image

from app.settings import Settings
from contract.card import FitRecord, load_card
from contract.errors import UserError
from contract.resample import inference_max_pixels
from harness.recordings import MOSD_CAMERA, write_aligned_bag, write_stray_scanner
from recordings.formats import ReadOptions, open_recording
from recordings.sevenscenes import SevenScenesReader
from trainer.evaluate import Predictor
from trainer.fit.state import FitState, new_fit_id, published_by
from trainer.quantize import calibration_frames


def frames(count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    mosd = SEVEN_SCENES.parent / "mosd-tabletop"
    out = []
    for colour in sorted((mosd / "color").glob("learn*.jpg"))[:count]:
        rgb = np.asarray(Image.open(colour).convert("RGB").resize((160, 120), Image.BILINEAR))
        depth = Image.open(mosd / "depth" / f"{colour.stem}.png").resize((160, 120), Image.NEAREST)
        out.append((rgb, np.asarray(depth, dtype=np.uint16)))
    return out


def test_resume_matches_a_published_version_by_the_fit_s_id_not_its_folder(registry, tmp_path):
    """An earlier fit of the same name in the same run folder published 0.1.0; this fit, interrupted before it
    published anything, must not take 0.1.0 for its own. The version whose card has its id is its own."""
    target = tmp_path / "registry" / "my-room" / "0.1.0"
    shutil.copytree(registry / "tiny" / "0.1.0", target)
    card = json.loads((target / "card.json").read_text())
    run = "runs/fit/my-room"
    card["name"] = "my-room"
    card["training"]["config"]["train"]["out_dir"] = f"{run}/train"  # the default run folder, relative
    fit = FitRecord(fit_id="the-earlier-fit", data="rec", start_from="scratch", budget_min=10, split={})
    card["training"]["fit"] = fit.model_dump(mode="json")
    (target / "card.json").write_text(json.dumps(card))
    assert load_card(target).training.fit.fit_id == "the-earlier-fit"
    config = type("Config", (), {"train": type("Train", (), {"out_dir": f"{run}/train"})()})()
    later = FitState.model_construct(fit_id="this-fit", config=config)
    assert published_by(later, tmp_path / "registry", "my-room") is None
    earlier = FitState.model_construct(fit_id="the-earlier-fit", config=config)
    assert published_by(earlier, tmp_path / "registry", "my-room") == target
    assert new_fit_id() != new_fit_id()
    # A fit.json from before fits had ids matches only a card without one, from its own training folder.
    legacy = FitState.model_construct(fit_id=None, config=config)
    assert published_by(legacy, tmp_path / "registry", "my-room") is None
    card["training"]["fit"]["fit_id"] = None
    (target / "card.json").write_text(json.dumps(card))
    assert published_by(legacy, tmp_path / "registry", "my-room") == target
    assert published_by(later, tmp_path / "registry", "my-room") is None


@pytest.mark.parametrize(
    ("kind", "options", "flag"),
    [
        ("strayscanner", ReadOptions(color_topic="/camera/color/image_raw"), "--color-topic"),
        ("strayscanner", ReadOptions(depth_topic="/camera/depth/image_raw"), "--depth-topic"),
        ("strayscanner", ReadOptions(max_gap_s=0.05), "--max-gap-ms"),
        ("rosbag", ReadOptions(min_confidence=1), "--min-confidence"),
        ("folders", ReadOptions(color_topic="/x"), "--color-topic"),
    ],
)
def test_an_option_the_format_has_no_use_for_is_refused_in_one_line(tmp_path, kind, options, flag):
    if kind == "strayscanner":
        path = write_stray_scanner(tmp_path / "scan", frames(2), MOSD_CAMERA.resized(160, 120))
    elif kind == "rosbag":
        path = write_aligned_bag(tmp_path / "rec.bag", "ros1", frames(2))
    else:
        path = tmp_path / "rec"
        (path / "color").mkdir(parents=True)
        (path / "depth").mkdir()
    with pytest.raises(UserError) as error:
        open_recording(path, kind, options, tmp_path / "scratch")
    assert str(error.value).startswith(f"{path}: {flag} does not apply to a {kind} recording (only to ")


def test_the_kinect_reader_refuses_topics_and_confidence(tmp_path):
    from test_kinect import tiny

    path = tiny(tmp_path / "k.mkv")
    for options, flag in ((ReadOptions(color_topic="/c"), "--color-topic"), (ReadOptions(min_confidence=2), "--min")):
        with pytest.raises(UserError, match=f"{flag}.* does not apply to a azurekinect recording"):
            open_recording(path, None, options, tmp_path / "scratch")
    assert len(open_recording(path, None, ReadOptions(max_gap_s=0.05), tmp_path / "scratch").pairs) == 2


def test_scores_and_int8_calibration_resample_by_the_service_s_pixel_limit(monkeypatch):
    """RGB2CLOUD_INFERENCE_MAX_PIXELS, as the service reads it, bounds what evaluate's predictor and int8
    calibration show the generator: a deployment that lowers it gets tables of the depth it serves."""
    monkeypatch.setenv("RGB2CLOUD_INFERENCE_MAX_PIXELS", str(160 * 120))
    seen = []

    def run(rgb: np.ndarray) -> np.ndarray:
        seen.append(rgb.shape[:2])
        return np.ones(rgb.shape[:2], np.float32)

    reader = SevenScenesReader(SEVEN_SCENES, "0-1")
    frame = reader[0]
    camera = frame.intrinsics  # 640x480: more than the limit at the model's own focal length
    depth = Predictor(run, camera, "counting")(frame.rgb, frame.intrinsics)
    assert depth.shape == (480, 640) and seen == [(120, 160)]
    photos = calibration_frames([reader], 2, camera)
    assert [p.shape[:2] for p in photos] == [(120, 160), (120, 160)]
    assert Settings().inference_max_pixels == inference_max_pixels() == 160 * 120  # the service reads the same
    monkeypatch.setenv("RGB2CLOUD_INFERENCE_MAX_PIXELS", "0")
    with pytest.raises(UserError, match="RGB2CLOUD_INFERENCE_MAX_PIXELS='0': expected a whole number of pixels"):
        inference_max_pixels()


def test_a_checkpoint_is_evaluated_without_its_training_data(trained_checkpoint, tmp_path):
    """The checkpoint carries its training camera: its config's training source can be gone (moved, another
    machine), and evaluating it on other data still works, at the camera it was trained at."""
    state = torch.load(trained_checkpoint, map_location="cpu", weights_only=True)
    assert state["camera"]["width"] == round(640 * 0.2) and state["camera"]["fx"] == pytest.approx(585 * 0.2)
    state["config"]["data"]["train"][0]["root"] = str(tmp_path / "moved-away")
    state["config"]["data"]["val"][0]["root"] = str(tmp_path / "moved-away")
    moved = tmp_path / "checkpoints" / "last.pt"
    moved.parent.mkdir()
    torch.save(state, moved)
    evaluate_cli(moved, tmp_path / "eval", "850-851")
    assert len(json.loads((tmp_path / "eval" / "metrics.json").read_text())["per_image"]) == 2


def test_a_fit_off_a_terminal_prints_each_phase_and_a_line_every_interval(capsys):
    """Under nohup, systemd or CI a fit must show signs of life: a line when each phase starts, and one at least
    every interval from a thread of its own, even while a phase runs no step (here, a quiet sleep)."""
    import time

    from trainer.fit.progress import Progress

    progress = Progress(600, time.monotonic(), live=False, every_s=0.1)
    progress.phase("measuring")
    time.sleep(0.35)
    progress.phase("training")
    progress.close()
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0].startswith("measuring: ") and lines[-1].startswith("training: ")
    assert sum(line.startswith("measuring: ") for line in lines) >= 3, lines  # the phase's line, then the thread's
    assert all("/600 s [" in line for line in lines)


def test_a_second_fit_into_a_folder_a_fit_is_writing_stops_at_once_naming_it(tmp_path):
    import os
    import subprocess
    import sys

    from conftest import REPO

    from trainer.fit.progress import RunLock

    run = tmp_path / "run"
    with RunLock(run):
        args = ["fit", str(SEVEN_SCENES), "--format", "7scenes", "--name", "x", "--licence", "y", "--out", str(run)]
        result = subprocess.run(
            [sys.executable, "-m", "cli", *args, "--budget", "1"], cwd=REPO, capture_output=True, text=True
        )
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines()[-1] == (
        f"error: {run}: a fit is already writing here (pid {os.getpid()}, started "
        f"{(run / 'fit.lock').read_text().split('started ')[1].strip()}); wait for it to end, or pass --out elsewhere"
    )
    with RunLock(run):  # released when its holder left, and free again
        pass
