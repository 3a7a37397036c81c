"""Network shapes at odd sizes, the objective's terms, and hole masking."""

from __future__ import annotations

import math

import pytest
import torch

from model.config import DiscriminatorConfig, GeneratorConfig
from model.losses import GANLoss, feature_matching, fill_holes, gradient_matching, masked_l1, patch_weights
from model.networks import GeneratorEnsemble, GlobalGenerator, MultiscaleDiscriminator


def test_paper_defaults():
    g, d = GeneratorConfig(), DiscriminatorConfig()
    assert (g.ngf, d.ndf, d.num_d, d.n_layers) == (32, 32, 2, 3)


@pytest.mark.parametrize("n_downsample,size", [(2, (36, 52)), (3, (24, 40)), (4, (48, 80))])
def test_generator_keeps_grid_sizes(n_downsample, size):
    g = GlobalGenerator(GeneratorConfig(ngf=4, n_downsample=n_downsample, n_blocks=1))
    y = g(torch.randn(2, 3, *size))
    assert y.shape == (2, 1, *size)
    assert y.abs().max() <= 1.0  # tanh


def test_work_scale_runs_the_network_on_a_pooled_image_and_upsamples_back():
    config = GeneratorConfig(ngf=4, n_downsample=2, n_blocks=1, work_scale=2)
    assert (config.core_multiple, config.input_multiple) == (4, 8)
    g = GlobalGenerator(config).eval()
    x = torch.randn(1, 3, 24, 40)
    y = g(x)
    assert y.shape == (1, 1, 24, 40)
    core = g(torch.nn.functional.avg_pool2d(x, 2), at_working_scale=True)
    assert core.shape == (1, 1, 12, 20)
    expected = torch.nn.functional.interpolate(core, scale_factor=2.0, mode="bilinear", align_corners=False)
    torch.testing.assert_close(y, expected)
    # The trainer's crops need only the core grid: 12x20 is not a multiple of 8 but of 4.
    assert g(torch.randn(1, 3, 12, 20), at_working_scale=True).shape == (1, 1, 12, 20)


def test_flip_average_is_the_mean_with_the_mirrored_prediction_at_inference_only():
    torch.manual_seed(0)
    config = GeneratorConfig(ngf=4, n_downsample=2, n_blocks=1, work_scale=2)
    plain = GlobalGenerator(config).eval()
    averaged = GlobalGenerator(config.model_copy(update={"flip_average": True})).eval()
    averaged.load_state_dict(plain.state_dict())
    x = torch.randn(1, 3, 24, 40)
    expected = 0.5 * (plain(x) + plain(x.flip(3)).flip(3))
    torch.testing.assert_close(averaged(x), expected)
    assert not torch.allclose(averaged(x), plain(x))
    torch.testing.assert_close(averaged(x.flip(3)), averaged(x).flip(3))  # mirror-equivariant by construction
    core = x[..., :12, :20]  # the trainer's path is untouched
    assert torch.equal(averaged(core, at_working_scale=True), plain(core, at_working_scale=True))


def test_skips_add_each_encoder_stage_to_the_decoder_stage_of_its_size_with_the_same_weights():
    torch.manual_seed(0)
    config = GeneratorConfig(ngf=4, n_downsample=2, n_blocks=1, work_scale=2)
    plain = GlobalGenerator(config).eval()
    skipped = GlobalGenerator(config.model_copy(update={"skips": True})).eval()
    skipped.load_state_dict(plain.state_dict())  # no new weights: the keys are a plain generator's
    x = torch.randn(1, 3, 16, 24)
    # By hand: front-end (layers 0-3), two downsamplings (4-6, 7-9), one block (10),
    # two upsamplings (11-13, 14-16), output (17-19).
    layers = list(plain.model)
    front = torch.nn.Sequential(*layers[:4])(x)
    half = torch.nn.Sequential(*layers[4:7])(front)
    bottleneck = torch.nn.Sequential(*layers[7:11])(half)
    up_half = torch.nn.Sequential(*layers[11:14])(bottleneck) + half
    up_full = torch.nn.Sequential(*layers[14:17])(up_half) + front
    expected = torch.nn.Sequential(*layers[17:])(up_full)
    torch.testing.assert_close(skipped(x, at_working_scale=True), expected)
    assert not torch.allclose(expected, plain(x, at_working_scale=True))
    assert skipped(x).shape == (1, 1, 16, 24)
    torch.testing.assert_close(torch.jit.script(skipped)(x), skipped(x))  # the TorchScript export's path


def test_global_offset_starts_as_the_plain_network_and_then_shifts_each_image_by_one_value():
    torch.manual_seed(0)
    config = GeneratorConfig(ngf=4, n_downsample=2, n_blocks=2, work_scale=2, dilations=[1, 2])
    plain = GlobalGenerator(config).eval()
    offset = GlobalGenerator(config.model_copy(update={"global_offset": True})).eval()
    missing, unexpected = offset.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and all(k.startswith("global_offset.") for k in missing)  # old keys unchanged
    x = torch.randn(2, 3, 32, 48)
    torch.testing.assert_close(offset(x), plain(x))  # the head's last convolution starts at zero
    with torch.no_grad():
        offset.global_offset[0].out.bias.fill_(0.25)
        raw_plain = torch.atanh(plain(x, at_working_scale=True).clamp(-0.999, 0.999))
        raw_offset = torch.atanh(offset(x, at_working_scale=True).clamp(-0.999, 0.999))
    torch.testing.assert_close(raw_offset - raw_plain, torch.full_like(raw_plain, 0.25), atol=2e-3, rtol=0)
    # With a non-zero head the offset depends on the image: two images get two values.
    with torch.no_grad():
        torch.nn.init.normal_(offset.global_offset[0].out.weight)
        shift = torch.atanh(offset(x, at_working_scale=True).clamp(-0.999, 0.999)) - raw_plain
    per_image = shift.flatten(1)
    assert torch.allclose(per_image, per_image[:, :1], atol=2e-3)
    assert not torch.isclose(per_image[0, 0], per_image[1, 0])
    convs = (torch.nn.Conv2d, torch.nn.ConvTranspose2d)
    actual = [tuple(m.weight.shape) for m in offset.modules() if isinstance(m, convs)]
    assert actual == offset.config.weight_shapes()
    torch.testing.assert_close(torch.jit.script(offset)(x), offset(x))  # the TorchScript export's path


def test_an_ensemble_outputs_the_mean_of_its_members_also_under_torchscript():
    config = GeneratorConfig(ngf=4, n_downsample=2, n_blocks=1, work_scale=2, flip_average=True)
    torch.manual_seed(0)
    members = [GlobalGenerator(config).eval() for _ in range(3)]
    ensemble = GeneratorEnsemble(members).eval()
    x = torch.randn(2, 3, 16, 24)
    expected = (members[0](x) + members[1](x) + members[2](x)) / 3
    torch.testing.assert_close(ensemble(x), expected)
    assert not torch.allclose(expected, members[0](x))
    torch.testing.assert_close(torch.jit.script(ensemble)(x), expected)
    with pytest.raises(ValueError, match="share one config"):
        GeneratorEnsemble([members[0], GlobalGenerator(config.model_copy(update={"flip_average": False}))])
    with pytest.raises(ValueError, match="at least two"):
        GeneratorEnsemble(members[:1])


def test_generator_layout_follows_the_paper():
    g = GlobalGenerator(GeneratorConfig(ngf=4, n_downsample=2, n_blocks=3))
    layers = list(g.model)
    assert isinstance(layers[0], torch.nn.ReflectionPad2d) and layers[1].kernel_size == (7, 7)
    assert sum(isinstance(m, torch.nn.ConvTranspose2d) for m in layers) == 2
    assert sum(type(m).__name__ == "ResnetBlock" for m in layers) == 3
    assert isinstance(layers[-1], torch.nn.Tanh) and layers[-2].kernel_size == (7, 7)
    assert all(not m.affine for m in g.modules() if isinstance(m, torch.nn.InstanceNorm2d))


@pytest.mark.parametrize("config", [GeneratorConfig(), GeneratorConfig(ngf=16, n_downsample=3, n_blocks=9)])
def test_weight_shapes_match_the_network(config):
    g = GlobalGenerator(config)
    actual = [tuple(m.weight.shape) for m in g.modules() if isinstance(m, torch.nn.Conv2d | torch.nn.ConvTranspose2d)]
    assert actual == config.weight_shapes()


def test_dilated_blocks_keep_the_weights_and_run_on_maps_smaller_than_their_dilation():
    plain = GeneratorConfig(ngf=4, n_downsample=2, n_blocks=2)
    dilated = plain.model_copy(update={"dilations": [1, 4]})
    g = GlobalGenerator(dilated).eval()
    firsts = [
        m.block[0] if isinstance(m.block[0], torch.nn.Conv2d) else m.block[1] for m in g.model if hasattr(m, "block")
    ]
    assert [(c.dilation, c.padding) for c in firsts] == [((1, 1), (0, 0)), ((4, 4), (4, 4))]
    actual = [tuple(m.weight.shape) for m in g.modules() if isinstance(m, torch.nn.Conv2d | torch.nn.ConvTranspose2d)]
    assert actual == plain.weight_shapes() == dilated.weight_shapes()
    # 8x8 -> a 2x2 map at the blocks: reflection padding of 4 would fail there, zero padding does not.
    assert g(torch.randn(1, 3, 8, 8)).shape == (1, 1, 8, 8)
    reference = GlobalGenerator(plain).eval()
    with torch.no_grad():  # the same weights, in the same order: only the taps' spacing differs
        for mine, theirs in zip(g.parameters(), reference.parameters(), strict=True):
            mine.copy_(theirs)
    x = torch.randn(1, 3, 32, 32)
    assert not torch.allclose(g(x), reference(x))


@pytest.mark.parametrize("dilations", [[1], [1, 2, 4], [1, 0]])
def test_dilations_need_one_positive_value_per_block(dilations):
    with pytest.raises(ValueError, match="one value >= 1 per residual block"):
        GeneratorConfig(n_blocks=2, dilations=dilations)


def test_noise_z_is_dropout_in_training_only():
    torch.manual_seed(0)
    g = GlobalGenerator(GeneratorConfig(ngf=4, n_downsample=1, n_blocks=2, dropout=0.5))
    x = torch.randn(1, 3, 16, 16)
    g.train()
    assert not torch.equal(g(x), g(x))
    g.eval()
    assert torch.equal(g(x), g(x))


@pytest.mark.parametrize("size", [(37, 53), (64, 48)])
def test_multiscale_discriminator_shapes(size):
    d = MultiscaleDiscriminator(DiscriminatorConfig(ndf=4), input_nc=4)
    outputs = d(torch.randn(2, 4, *size))
    assert len(outputs) == 2  # D1 full resolution, D2 half
    for scale in outputs:
        assert len(scale) == 3 + 2  # n_layers convs + the stride-1 conv + the logits
        assert scale[-1].shape[1] == 1
    h1, w1 = outputs[0][-1].shape[-2:]
    h2, w2 = outputs[1][-1].shape[-2:]
    assert h2 < h1 and w2 < w1
    # D2 sees exactly the count_include_pad=False average pool of the input.
    x = torch.ones(1, 4, *size)
    pooled = torch.nn.functional.avg_pool2d(x, 3, 2, 1, count_include_pad=False)
    assert torch.allclose(pooled, torch.ones_like(pooled))


def _fake_outputs(value: float, num_d: int = 2, n_layers: int = 3) -> list[list[torch.Tensor]]:
    return [[torch.full((1, 2, 5, 5), value) for _ in range(n_layers + 2)] for _ in range(num_d)]


def test_gan_losses_hand_computed():
    out = [[torch.zeros(1, 1, 3, 3)], [torch.zeros(1, 1, 2, 2)]]
    assert GANLoss("lsgan")(out, True).item() == pytest.approx(2 * 1.0)
    assert GANLoss("lsgan")(out, False).item() == pytest.approx(0.0)
    assert GANLoss("vanilla")(out, True).item() == pytest.approx(2 * math.log(2))


def test_feature_matching_zero_when_fake_equals_real():
    d = MultiscaleDiscriminator(DiscriminatorConfig(ndf=4), input_nc=4)
    x = torch.randn(1, 4, 32, 32)
    assert feature_matching(d(x), d(x)).item() == 0.0


def test_feature_matching_weights_match_pix2pixhd():
    # Constant difference c: 2 scales x 4 layers x (4 / (3 + 1)) x (1 / 2) x c = 4c.
    assert feature_matching(_fake_outputs(0.75), _fake_outputs(0.5)).item() == pytest.approx(4 * 0.25)


def test_holes_carry_no_signal():
    real = torch.tensor([[[[0.5, -1.0], [0.2, -1.0]]]])
    fake = torch.full_like(real, 0.9)
    valid = torch.tensor([[[[1.0, 0.0], [1.0, 0.0]]]])
    filled = fill_holes(real, fake, valid)
    assert torch.equal(filled, torch.tensor([[[[0.5, 0.9], [0.2, 0.9]]]]))
    assert masked_l1(fake, real, valid).item() == pytest.approx((0.4 + 0.7) / 2)
    # A frame with no valid depth contributes nothing to D's "real" loss or to feature matching.
    d = MultiscaleDiscriminator(DiscriminatorConfig(ndf=4), input_nc=4)
    outputs = d(torch.randn(1, 4, 32, 32))
    weights = patch_weights(torch.zeros(1, 1, 32, 32), outputs)
    assert GANLoss("lsgan")(outputs, True, weights).item() == 0.0
    assert feature_matching(outputs, d(torch.randn(1, 4, 32, 32)), weights).item() == 0.0


def test_gradient_matching_scores_shape_not_scale_and_skips_holes():
    real = torch.rand(1, 1, 32, 32)
    valid = torch.ones_like(real)
    # A constant offset in log depth is one wrong distance for the whole view: no cost.
    assert gradient_matching(real + 0.3, real, valid).item() == pytest.approx(0.0, abs=1e-6)
    # One step edge 1.0 high in the residual, at column 16: hand-computed per scale.
    step = torch.zeros_like(real)
    step[..., 16:] = 1.0
    # Scale 2^k keeps every 2^k-th pixel: the edge is one of 32 / 2^k - 1 horizontal pairs
    # per row, and no vertical pair differs.
    expected = sum(1.0 / (32 // 2**k - 1) for k in range(4)) / 4
    assert gradient_matching(real + step, real, valid).item() == pytest.approx(expected)
    # Pairs that touch a hole are ignored, whatever the prediction does there.
    holes = valid.clone()
    holes[..., 16] = 0.0
    spike = torch.zeros_like(real)
    spike[..., 16] = 5.0
    assert gradient_matching(real + spike, real, holes).item() == pytest.approx(0.0, abs=1e-6)
