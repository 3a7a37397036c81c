"""Export parity, the published card, and the registry's immutability."""

from __future__ import annotations

import json
import subprocess
import sys
from datetime import UTC, datetime

import numpy as np
import onnx
import pytest
from conftest import FLOAT32_METRICS, REPO, SEVEN_SCENES, TUM_FRAME, evaluate_cli, export_args, run_cli
from PIL import Image

from contract.card import (
    ONNX_FILE,
    SAMPLE_FILE,
    TORCHSCRIPT_FILE,
    WEIGHTS_FILE,
    CardError,
    DataRef,
    Metrics,
    ModelCard,
    Training,
    list_versions,
    load_card,
    publish,
    verify_files,
)
from contract.codec import INPUT_ENCODING, DepthEncoding
from contract.geometry import ColourCamera, Intrinsics
from contract.runtime import OnnxGenerator
from contract.spec import GeneratorSpec, InferenceSettings
from trainer.checkpoint import load_graph
from trainer.export import check_parity, export_onnx, export_torchscript, metrics_from_report, parity_sizes


@pytest.fixture(scope="module")
def evaluated(trained_checkpoint, tmp_path_factory):
    out = tmp_path_factory.mktemp("eval")
    result = evaluate_cli(trained_checkpoint, out, "850-852", samples=2)
    return out, result.stdout


def test_evaluate_prints_the_paper_table_and_writes_reports(evaluated):
    out, stdout = evaluated
    assert "| paper (TUM, Table 2) | 0.107 | 0.548 | 0.047 | 0.942 | 0.984 | 0.990 | 0.420 |" in stdout
    report = json.loads((out / "metrics.json").read_text())
    assert report["split"] == "7scenes-redkitchen 850-852"
    assert report["metrics"]["images"] == 3 and len(report["per_image"]) == 3
    assert 0 < report["metrics"]["delta1"] <= report["metrics"]["delta2"] <= report["metrics"]["delta3"] <= 1
    for name in ("metrics.md", "pc_rmse_curve.png", "samples.png"):
        assert (out / name).stat().st_size > 0
    with Image.open(out / "samples.png") as im:
        assert im.size == (3 * 640, 2 * 480)  # RGB | predicted | truth, full resolution


@pytest.mark.slow
def test_parity_at_two_sizes_one_off_grid(trained_checkpoint, tmp_path):
    graph, weights = load_graph(trained_checkpoint)
    config = weights.config
    export_onnx(graph, tmp_path / ONNX_FILE)
    export_torchscript(graph, tmp_path / TORCHSCRIPT_FILE)
    model = onnx.load(str(tmp_path / ONNX_FILE))
    assert not any(t.data_location == onnx.TensorProto.EXTERNAL for t in model.graph.initializer)  # one file
    image = np.asarray(Image.open(TUM_FRAME / "TUM_color.png").convert("RGB"))
    report = check_parity(graph, tmp_path, image)
    assert len(report) == 4 and max(report.values()) <= 1e-4
    sizes = parity_sizes(480, 640, config.generator.input_multiple)
    assert any(h % 4 or w % 4 for h, w in sizes)
    runner = OnnxGenerator(tmp_path / ONNX_FILE, config.generator.input_multiple)
    assert runner.predict_raw(image[: 481 - 4, : 641 - 6]).shape == (477, 635)


@pytest.mark.slow
def test_a_published_version_runs_and_publishes_again_with_other_inference_settings(
    trained_checkpoint, evaluated, tmp_path
):
    """A version whose checkpoint is gone: its TorchScript weights run with a colour-weighted median,
    then publish as a new version whose ONNX graph carries it."""
    out, _ = evaluated
    run_cli(*export_args(trained_checkpoint, out / "metrics.json", tmp_path))
    source = tmp_path / "tiny" / "0.1.0"
    median = ["--inference", "median_radius=1", "--inference", "median_sigma=0.2", "--inference", "median_spacing=2"]
    stdout = evaluate_cli(source, tmp_path / "eval-source", "850-851", *median).stdout
    assert "tiny 0.1.0 (eager, colour-weighted median 3x3 taps 2 px apart, sigma 0.2)" in stdout
    evaluate_cli(trained_checkpoint, tmp_path / "eval-checkpoint", "850-851", *median)
    from_source, from_checkpoint = (
        json.loads((tmp_path / name / "metrics.json").read_text())["metrics"]
        for name in ("eval-source", "eval-checkpoint")
    )
    # The same weights, run the same way, in two processes: not bit for bit (a CI machine gave REL
    # 0.36057048 against 0.36057079), but within float32's agreement; the same frames and pixels exactly.
    assert from_source == pytest.approx(from_checkpoint, **FLOAT32_METRICS)
    assert (from_source["images"], from_source["pixels"]) == (from_checkpoint["images"], from_checkpoint["pixels"])
    # The median is in use: frame 850 without it (the plain evaluation, 850-852) scores otherwise.
    plain, with_median = (
        next(row for row in json.loads(path.read_text())["per_image"] if row["name"].endswith("000850"))
        for path in (out / "metrics.json", tmp_path / "eval-source" / "metrics.json")
    )
    assert with_median["rel"] != pytest.approx(plain["rel"], **FLOAT32_METRICS)

    args = export_args(source, tmp_path / "eval-source" / "metrics.json", tmp_path)
    args[args.index("0.1.0")] = "0.2.0"
    assert "parity onnx@" in run_cli(*args, *median).stdout
    derived, original = load_card(tmp_path / "tiny" / "0.2.0"), load_card(source)
    assert derived.derived_from == "tiny 0.1.0" and original.derived_from is None
    assert derived.training == original.training and derived.camera == original.camera
    assert derived.generator == original.generator  # the architecture is the weights'
    assert derived.inference == InferenceSettings(median_radius=1, median_sigma=0.2, median_spacing=2)
    assert original.inference == InferenceSettings()
    evaluate_cli(tmp_path / "tiny" / "0.2.0", tmp_path / "eval-derived", "850-851")
    onnx_metrics = json.loads((tmp_path / "eval-derived" / "metrics.json").read_text())["metrics"]
    for key in ("rel", "rmse", "delta1", "pc_rmse_mean"):
        assert abs(onnx_metrics[key] - from_source[key]) < 1e-4


def test_evaluate_refuses_an_unknown_inference_setting_in_one_line(trained_checkpoint, tmp_path):
    args = ["--format", "7scenes", "--root", str(SEVEN_SCENES), "--frames", "850", "--out", str(tmp_path)]
    result = subprocess.run(
        [sys.executable, "-m", "cli", "evaluate", str(trained_checkpoint), *args, "--inference", "ngf=8"],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 1 and result.stderr.startswith("error: --inference 'ngf=8'")
    assert "Traceback" not in result.stderr


@pytest.mark.slow
def test_export_publishes_a_complete_card_and_refuses_to_overwrite(trained_checkpoint, evaluated, tmp_path):
    out, _ = evaluated
    args = export_args(trained_checkpoint, out / "metrics.json", tmp_path / "registry")
    stdout = run_cli(*args).stdout
    assert "parity onnx@" in stdout and "published" in stdout
    folder = tmp_path / "registry" / "tiny" / "0.1.0"
    card = load_card(folder)
    verify_files(folder, card)
    assert set(card.files) == {ONNX_FILE, TORCHSCRIPT_FILE, WEIGHTS_FILE, SAMPLE_FILE} and card.sample == SAMPLE_FILE
    with Image.open(folder / SAMPLE_FILE) as sample:  # the parity photo as the generator is shown it
        assert sample.size == (card.camera.width, card.camera.height)
    assert card.generator.ngf == 8 and card.input_multiple == 8
    assert card.depth_encoding.kind == "log"
    # The camera the generator was trained at: 7-Scenes' 640x480 (fx 585, cx 320) at data.val_scale 0.2.
    assert (card.camera.fx, card.camera.cx, card.camera.width) == pytest.approx((117.0, 63.6, 128))
    assert "non-commercial" in card.training.data[0].licence and card.training.data[0].frames == "0-3"
    assert card.metrics[0].split == "7scenes-redkitchen 850-852"
    assert card.metrics[0].colour_camera is None  # scored pixel to pixel, and the card says so
    assert card.training.steps == 6 and card.training.hardware
    assert card.trainer_commit
    assert max(card.parity.values()) <= 1e-4

    # The published version scores as its checkpoint does, through ONNX Runtime.
    stdout = evaluate_cli(folder, tmp_path / "eval-onnx", "850-852").stdout
    assert "| tiny 0.1.0 (ONNX) |" in stdout
    onnx_metrics = json.loads((tmp_path / "eval-onnx" / "metrics.json").read_text())["metrics"]
    eager_metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    for key in ("rel", "rmse", "delta1", "pc_rmse_mean"):
        assert abs(onnx_metrics[key] - eager_metrics[key]) < 1e-4

    again = subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, capture_output=True, text=True)
    assert again.returncode == 1 and again.stderr.startswith("error: ") and "already exists" in again.stderr
    assert "Traceback" not in again.stderr
    assert load_card(folder) == card  # untouched


def test_a_card_says_its_metrics_were_read_at_the_colour_camera(trained_checkpoint, tmp_path):
    camera = "{fx: 530, fy: 530, cx: 314.5, cy: 239, baseline_m: 0.009}"
    evaluate_cli(trained_checkpoint, tmp_path, "850", "--colour-camera", camera)
    report = json.loads((tmp_path / "metrics.json").read_text())
    expected = ColourCamera(fx=530, fy=530, cx=314.5, cy=239, baseline_m=0.009)
    assert report["read_at_colour_camera"] == expected.model_dump()
    assert metrics_from_report(tmp_path / "metrics.json").colour_camera == expected


def _card(version: str) -> ModelCard:
    return ModelCard(
        name="tiny",
        version=version,
        created=datetime.now(UTC),
        files={},
        generator=GeneratorSpec(),
        inference=InferenceSettings(),
        input_multiple=16,
        input_encoding=INPUT_ENCODING,
        depth_encoding=DepthEncoding(),
        camera=Intrinsics(fx=585, fy=585, cx=320, cy=240, width=640, height=480),
        training=Training(
            data=[DataRef(name="x", format="7scenes", frames="0-1", licence="MIT")],
            steps=1,
            duration_s=1.0,
            hardware="cpu",
            config={},
        ),
        metrics=[
            Metrics(
                split="x 2-3",
                images=2,
                depth_range_m=(0.1, 10.0),
                rel=0.1,
                rmse=0.1,
                log10=0.1,
                delta1=0.9,
                delta2=0.95,
                delta3=0.99,
                pc_rmse_mean=0.2,
            )
        ],
        trainer_commit="abc",
    )


def test_registry_verifies_orders_versions_and_never_overwrites(tmp_path):
    payload = tmp_path / "weights.bin"
    payload.write_bytes(b"generator bytes")
    folder = publish(tmp_path / "reg", _card("1.0.0"), {"weights.bin": payload})
    card = load_card(folder)
    verify_files(folder, card)
    (folder / "weights.bin").write_bytes(b"tampered")
    with pytest.raises(CardError, match=r"weights\.bin: sha256"):
        verify_files(folder, card)
    (folder / "weights.bin").unlink()
    with pytest.raises(CardError, match=r"weights\.bin: listed in the card but missing"):
        verify_files(folder, card)
    publish(tmp_path / "reg", _card("1.10.0"), {"weights.bin": payload})
    publish(tmp_path / "reg", _card("1.2.0-rc.1"), {"weights.bin": payload})
    assert list_versions(tmp_path / "reg", "tiny") == ["1.0.0", "1.2.0-rc.1", "1.10.0"]
    with pytest.raises(FileExistsError):
        publish(tmp_path / "reg", _card("1.0.0"), {"weights.bin": payload})
    with pytest.raises(ValueError, match="semantic version"):
        _card("v1")


@pytest.mark.slow
def test_the_onnx_path_runs_on_the_contract_alone_without_torch(trained_checkpoint, tmp_path):
    """What the service needs (geometry, codec, card, runtime on ONNX) works without torch."""
    graph, weights = load_graph(trained_checkpoint)
    config = weights.config
    export_onnx(graph, tmp_path / ONNX_FILE)
    code = f"""
import sys
import numpy as np
from contract import card, codec, geometry, runtime, spec
g = runtime.OnnxGenerator({str(tmp_path / ONNX_FILE)!r}, {config.generator.input_multiple})
y = g.predict_raw(np.zeros((30, 41, 3), np.uint8))
assert y.shape == (30, 41), y.shape
depth = codec.DepthEncoding().decode(y)
assert "torch" not in sys.modules, "torch was imported"
print("ok")
"""
    result = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr


def test_export_refuses_a_bundled_models_name_as_fit_does(trained_checkpoint, tmp_path):
    """The user's version would shadow the bundled model the service and fit rely on."""
    metrics = tmp_path / "metrics.json"
    metrics.write_text("{}")
    args = export_args(trained_checkpoint, metrics, tmp_path / "registry")
    args[args.index("--name") + 1] = "rgb2cloud-7scenes"
    result = subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, capture_output=True, text=True)
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert result.stderr.startswith("error: --name rgb2cloud-7scenes: a bundled model has this name")
    assert not (tmp_path / "registry").exists()


def test_evaluate_scores_a_folder_recording_without_intrinsics_json_at_the_camera_given(
    trained_checkpoint, evaluated, tmp_path
):
    """aims-lab ships no intrinsics.json: ``--fx --fy --cx --cy`` give its camera, as fit's do; on 7-Scenes,
    whose camera is its own, they are refused in one line, before any model loads."""

    def evaluate(*args: str) -> subprocess.CompletedProcess:
        command = [sys.executable, "-m", "cli", "evaluate", str(trained_checkpoint), *args]
        return subprocess.run(command, cwd=REPO, capture_output=True, text=True)

    aims_lab = ["--format", "folders", "--root", str(SEVEN_SCENES.parent / "aims-lab"), "--frames", "160-161"]
    camera = ["--fx", "585", "--fy", "585", "--cx", "320", "--cy", "240"]
    unknown = evaluate(*aims_lab, "--out", str(tmp_path / "a"))
    assert unknown.returncode == 1 and "no camera intrinsics" in unknown.stderr
    scored = evaluate(*aims_lab, *camera, "--out", str(tmp_path / "b"))
    assert scored.returncode == 0, scored.stderr
    report = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert report["metrics"]["images"] == 2 and report["camera_given"] == {"fx": 585, "fy": 585, "cx": 320, "cy": 240}
    assert json.loads((evaluated[0] / "metrics.json").read_text())["camera_given"] is None  # 7-Scenes' own
    seven_scenes = ["--format", "7scenes", "--root", str(SEVEN_SCENES), "--frames", "850"]
    refused = evaluate(*seven_scenes, *camera, "--out", str(tmp_path / "c"))
    assert refused.returncode == 1 and refused.stderr.startswith("error: --fx, --fy, --cx, --cy and --depth-scale")
    assert not (tmp_path / "c").exists()
    lab = ["--format", "folders", "--root", str(SEVEN_SCENES.parent / "aims-lab")]
    medians = run_cli("baselines", *lab, "--train-frames", "0-9", "--test-frames", "160-161", *camera).stdout
    assert "median" in medians
    assert "Traceback" not in refused.stderr
