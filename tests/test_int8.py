"""The int8 graph: exported beside the fp32 one, parity-checked, listed in the card, and served on request.

The model is the tiny one trained for a few steps on real RedKitchen frames; calibration
reads its own training frames, as ``export --precision int8`` does for any model.
"""

from __future__ import annotations

import io

import httpx
import numpy as np
import onnx
import pytest
from conftest import REPO, SEVEN_SCENES, TUM_FRAME, evaluate_cli, export_args, run_cli, tiny_config, write_config
from PIL import Image

from contract.card import (
    CARD_FILE,
    INT8_ONNX_FILE,
    ONNX_FILE,
    SAMPLE_FILE,
    TORCHSCRIPT_FILE,
    WEIGHTS_FILE,
    load_card,
    publish,
    sha256_file,
)
from contract.runtime import OnnxGenerator, disagreement
from harness.service import running_service
from trainer.quantize import int8_parity, quantize_generator

PHOTO = (TUM_FRAME / "TUM_color.png").read_bytes()
INT8_FILES = (ONNX_FILE, TORCHSCRIPT_FILE, INT8_ONNX_FILE, SAMPLE_FILE)


@pytest.fixture(scope="module")
def int8_registry(tmp_path_factory):
    """A tiny model published with ``export --precision int8``; the export's own output beside it.

    It trains 60 steps, not the 6 of the shared tiny checkpoint: a generator that has learned next to nothing
    draws depth from noise that int8 cannot hold to fp32's 1.10x on 95% of pixels (95.0% at 6 steps, 96.9% at 60,
    on 2 AMD EPYC cores), where a trained one does (the bundled graph's figures: docs/api.md).
    """
    out = tmp_path_factory.mktemp("int8")
    config = tiny_config(out / "run", train={"steps": 60}, generator={"work_scale": 2})
    config["data"]["transform"].update(extent=[0.5, 1.0], whole_share=0.5)
    run_cli("train", str(write_config(out / "config.yaml", config)))
    checkpoint = out / "run" / "checkpoints" / "last.pt"
    evaluate_cli(checkpoint, out / "eval", "850-851")
    result = run_cli(*export_args(checkpoint, out / "eval" / "metrics.json", out / "weights"), "--precision", "int8")
    return out / "weights", result.stdout


def test_export_writes_an_int8_graph_beside_the_fp32_one_and_the_card_says_how(int8_registry):
    registry, stdout = int8_registry
    version = registry / "tiny" / "0.1.0"
    card = load_card(version)
    assert set(card.files) == {ONNX_FILE, TORCHSCRIPT_FILE, WEIGHTS_FILE, INT8_ONNX_FILE, SAMPLE_FILE}
    assert card.sample == SAMPLE_FILE
    with Image.open(version / SAMPLE_FILE) as sample:  # the parity photo, at the card camera's size
        assert sample.size == (card.camera.width, card.camera.height)
    for name, digest in card.files.items():
        assert sha256_file(version / name) == digest and f"{name}  sha256 {digest}" in stdout
    assert card.int8 is not None and card.int8.file == INT8_ONNX_FILE
    assert card.int8.calibration == "percentile" and card.int8.frames == 4  # the tiny config trains on 4 frames
    assert card.int8.frames_from == ["7scenes-redkitchen 0-3"]
    assert "Collecting tensor data" not in stdout  # ONNX Runtime's calibration chatter is not the command's output
    # Every convolution is an integer one: each weight is stored in int8, none left in fp32.
    graph = onnx.load(str(version / INT8_ONNX_FILE)).graph
    assert card.int8.fp32_nodes == []
    weights = {t.name: t for t in graph.initializer}
    convolutions = [node for node in graph.node if node.op_type in ("Conv", "ConvTranspose")]
    producers = {out: node for node in graph.node for out in node.output}
    for node in convolutions:
        dequantised = producers[node.input[1]]  # the weight comes through a DequantizeLinear of int8
        assert dequantised.op_type == "DequantizeLinear"
        assert weights[dequantised.input[0]].data_type == onnx.TensorProto.INT8
        # 7-bit weights (reduce_range): |w| <= 64, so no pair of uint8 x int8 products (255 x 64 x 2 = 32,640)
        # saturates the 16-bit sums of a CPU without VNNI.
        values = onnx.numpy_helper.to_array(weights[dequantised.input[0]])
        assert values.min() >= -64 and values.max() <= 64
    assert "parity int8 (the worse of the parity photo and its double): median relative difference" in stdout


def test_int8_depth_agrees_with_fp32_within_the_tolerance_on_other_photos(int8_registry):
    registry, _ = int8_registry
    version = registry / "tiny" / "0.1.0"
    card = load_card(version)
    assert disagreement(card.int8.parity) is None
    kitchen = SEVEN_SCENES / "frame-000900.color.jpg"  # a test frame: not among the calibration frames
    with Image.open(kitchen) as im:
        photo = np.asarray(im.convert("RGB"))
    parity = int8_parity(version / ONNX_FILE, version / INT8_ONNX_FILE, photo, card.input_multiple, card.depth_encoding)
    assert disagreement(parity) is None
    # And the two graphs are not the same graph: int8 changes the numbers a little.
    fp32 = OnnxGenerator(version / ONNX_FILE, card.input_multiple).predict_raw(photo)
    int8 = OnnxGenerator(version / INT8_ONNX_FILE, card.input_multiple).predict_raw(photo)
    assert 0 < np.abs(fp32 - int8).max() < 0.5


def test_evaluate_scores_the_int8_graph_and_refuses_a_version_without_one(int8_registry, registry, tmp_path):
    int8_version = int8_registry[0] / "tiny" / "0.1.0"
    result = evaluate_cli(int8_version, tmp_path / "eval", "850-851", "--precision", "int8")
    assert "| tiny 0.1.0 (ONNX int8) |" in result.stdout
    refused = run_cli_failing(
        "evaluate", str(registry / "tiny" / "0.1.0"), "--format", "7scenes", "--precision", "int8"
    )
    assert "no int8 graph" in refused


def run_cli_failing(*args: str) -> str:
    import subprocess
    import sys

    result = subprocess.run(
        [sys.executable, "-m", "cli", *args, "--root", str(SEVEN_SCENES), "--frames", "850"],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert result.returncode != 0 and "Traceback" not in result.stderr
    return result.stdout + result.stderr


def depth(url: str, **params: str) -> httpx.Response:
    return httpx.post(f"{url}/depth", files={"image": ("p.png", PHOTO)}, params=params, timeout=60)


def _png(response: httpx.Response) -> np.ndarray:
    assert response.status_code == 200, response.text
    with Image.open(io.BytesIO(response.content)) as im:
        return np.asarray(im).astype(np.float64)


def not_bf16(listed: list[dict]) -> dict[str, list[str]]:
    """Each model's precisions in /v1/models, leaving out bf16: where this CPU has bf16 units, a loaded version
    lists it beside fp32 once it checked out and ran faster (tests/test_engines.py checks that)."""
    return {m["name"]: [p for p in m["versions"][0]["card"]["precisions"] if p != "bf16"] for m in listed}


@pytest.fixture
def both(int8_registry, registry, tmp_path):
    """A registry with the int8 version (``quant``) and one without an int8 graph (``plain``)."""
    target = tmp_path / "weights"
    with_int8 = int8_registry[0] / "tiny" / "0.1.0"
    card = load_card(with_int8).model_copy(update={"name": "quant"})
    publish(target, card, {f: with_int8 / f for f in INT8_FILES})
    plain = registry / "tiny" / "0.1.0"
    card = load_card(plain).model_copy(update={"name": "plain"})
    publish(target, card, {f: plain / f for f in (ONNX_FILE, TORCHSCRIPT_FILE, SAMPLE_FILE)})
    return target


def test_the_service_serves_both_precisions_and_names_the_one_used(both):
    env = {"registry": str(both), "model": "quant", "threads": "1"}
    with running_service(**env) as service:
        fp32 = depth(service.url, precision="fp32")
        assert fp32.headers["x-precision"] == "fp32" and "x-precision-fallback" not in fp32.headers
        int8 = depth(service.url, precision="int8")
        assert int8.headers["x-precision"] == "int8"
        a, b = _png(fp32), _png(int8)
        valid = (a > 0) & (b > 0)
        assert not np.array_equal(a, b) and (np.maximum(a, b)[valid] / np.minimum(a, b)[valid] < 1.25).mean() > 0.9

        plain = depth(service.url, model="plain", precision="int8")
        assert plain.headers["x-precision"] == "fp32"
        assert plain.headers["x-precision-fallback"] == "int8 asked for; this version has no int8 graph"

        wrong = depth(service.url, precision="fp16")
        assert wrong.status_code == 422 and "precision" in wrong.text

        assert not_bf16(models(service.url)) == {"quant": ["fp32", "int8"], "plain": ["fp32"]}

    with running_service(**env, precision="int8") as service:
        assert depth(service.url).headers["x-precision"] == "int8"
        assert depth(service.url, precision="fp32").headers["x-precision"] == "fp32"


def test_a_version_whose_int8_file_does_not_match_its_card_is_refused(both):
    tampered = both / "quant" / "0.1.0"
    card = load_card(tampered).model_copy(update={"version": "0.2.0"})
    files = {f: tampered / f for f in INT8_FILES}
    broken = publish(both, card, files)
    int8_file = broken / INT8_ONNX_FILE
    int8_file.write_bytes(int8_file.read_bytes()[:-16])
    env = {"registry": str(both), "model": "plain", "threads": "1"}
    with running_service(**env) as service:
        refused = depth(service.url, model="quant:0.2.0")
        assert refused.status_code == 409
        assert INT8_ONNX_FILE in refused.json()["detail"] and "sha256" in refused.json()["detail"]
        # fp32 was not asked for either: the version is refused whole, and the one before keeps serving.
        assert depth(service.url, model="quant").headers["x-model-version"] == "0.1.0"
    assert (broken / CARD_FILE).is_file()


@pytest.mark.parametrize("engine", ["auto", "openvino"])
def test_an_int8_graph_that_disagrees_with_fp32_where_it_loads_is_not_served(both, tmp_path, engine):
    """Export checked int8 on its own machine; every machine that loads the version checks again, on the sample
    photo the version ships. An int8 graph whose integer arithmetic gives other depth (here: calibrated on black
    frames, as a CPU that saturates would compute) is not served: asked for by name, 409; by default, fp32 with
    the reason; and /v1/models lists fp32 alone for it."""
    good = both / "quant" / "0.1.0"
    card = load_card(good)
    black = [np.zeros((card.camera.height, card.camera.width, 3), np.uint8)] * 4
    broken = tmp_path / INT8_ONNX_FILE
    quantize_generator(good / ONNX_FILE, broken, black, card.input_multiple, "minmax", "none")
    files = {f: good / f for f in INT8_FILES} | {INT8_ONNX_FILE: broken}
    name = f"saturating-{engine}"
    publish(both, card.model_copy(update={"name": name}), files)
    with running_service(registry=str(both), model=name, threads="1", precision="int8", engine=engine) as service:
        asked = depth(service.url, precision="int8")
        assert asked.status_code == 409
        assert "its int8 graph disagrees with fp32 on this machine" in asked.json()["detail"]
        fallback = depth(service.url)
        assert fallback.status_code == 200 and fallback.headers["x-precision"] == "fp32"
        assert fallback.headers["x-precision-fallback"].startswith("int8 asked for; its int8 graph disagrees")
        if engine == "openvino":
            assert fallback.headers["x-engine"] == "openvino"
        listed = not_bf16(models(service.url))
        assert listed[name] == ["fp32"] and listed["quant"] == ["fp32", "int8"]
        assert depth(service.url, model="quant", precision="int8").headers["x-precision"] == "int8"


def test_cors_exposes_the_precision_headers(both):
    with running_service(registry=str(both), model="plain", threads="1", cors_origins='["http://example.test"]') as s:
        r = httpx.post(
            f"{s.url}/depth",
            files={"image": ("p.png", PHOTO)},
            params={"precision": "int8"},
            headers={"Origin": "http://example.test"},
            timeout=60,
        )
        exposed = {h.strip().lower() for h in r.headers["access-control-expose-headers"].split(",")}
        assert {"x-precision", "x-precision-fallback", "x-engine"} <= exposed


def models(url: str) -> list[dict]:
    return httpx.get(f"{url}/v1/models", timeout=10).json()["models"]
