"""Network shapes at odd sizes, the objective's terms, and hole masking."""

from __future__ import annotations

import math

import pytest
import torch

from contract.spec import GeneratorSpec, InferenceSettings
from trainer.config import DiscriminatorConfig
from trainer.inference import InferenceGraph
from trainer.losses import GANLoss, feature_matching, fill_holes, masked_l1, patch_weights
from trainer.networks import GlobalGenerator, MultiscaleDiscriminator


def test_paper_defaults():
    g, d = GeneratorSpec(), DiscriminatorConfig()
    assert (g.ngf, d.ndf, d.num_d, d.n_layers) == (32, 32, 2, 3)


@pytest.mark.parametrize("n_downsample,size", [(2, (36, 52)), (3, (24, 40)), (4, (48, 80))])
def test_generator_keeps_grid_sizes(n_downsample, size):
    g = GlobalGenerator(GeneratorSpec(ngf=4, n_downsample=n_downsample, n_blocks=1))
    y = g(torch.randn(2, 3, *size))
    assert y.shape == (2, 1, *size)
    assert y.abs().max() <= 1.0  # tanh


def test_the_inference_graph_pools_runs_the_network_and_upsamples_back():
    spec = GeneratorSpec(ngf=4, n_downsample=2, n_blocks=1, work_scale=2)
    assert (spec.core_multiple, spec.input_multiple) == (4, 8)
    g = GlobalGenerator(spec).eval()
    graph = InferenceGraph(g, InferenceSettings()).eval()
    x = torch.randn(1, 3, 24, 40)
    y = graph(x)
    assert y.shape == (1, 1, 24, 40)
    core = g(torch.nn.functional.avg_pool2d(x, 2))
    assert core.shape == (1, 1, 12, 20)
    expected = torch.nn.functional.interpolate(core, scale_factor=2.0, mode="bilinear", align_corners=False)
    torch.testing.assert_close(y, expected)
    # The trainer's crops need only the core grid: 12x20 is not a multiple of 8 but of 4.
    assert g(torch.randn(1, 3, 12, 20)).shape == (1, 1, 12, 20)
    # Its state dict is the generator's under "generator.": the refinements have no weights.
    assert list(graph.state_dict()) == [f"generator.{key}" for key in g.state_dict()]
    torch.testing.assert_close(torch.jit.script(graph)(x), y)  # the TorchScript export's path


def test_generator_layout_follows_the_paper():
    g = GlobalGenerator(GeneratorSpec(ngf=4, n_downsample=2, n_blocks=3))
    layers = list(g.model)
    assert isinstance(layers[0], torch.nn.ReflectionPad2d) and layers[1].kernel_size == (7, 7)
    assert sum(isinstance(m, torch.nn.ConvTranspose2d) for m in layers) == 2
    assert sum(type(m).__name__ == "ResnetBlock" for m in layers) == 3
    assert isinstance(layers[-1], torch.nn.Tanh) and layers[-2].kernel_size == (7, 7)
    assert all(not m.affine for m in g.modules() if isinstance(m, torch.nn.InstanceNorm2d))


@pytest.mark.parametrize(
    "config",
    [
        GeneratorSpec(),
        GeneratorSpec(ngf=16, n_downsample=3, n_blocks=9),
        GeneratorSpec(ngf=8, n_downsample=3, n_blocks=2, upsampler="bilinear"),
        GeneratorSpec(ngf=8, n_downsample=3, n_blocks=2, upsampler="shuffle"),
        GeneratorSpec(ngf=8, n_downsample=3, n_blocks=2, upsampler="resize"),
    ],
)
def test_weight_shapes_match_the_network(config):
    g = GlobalGenerator(config)
    actual = [tuple(m.weight.shape) for m in g.modules() if isinstance(m, torch.nn.Conv2d | torch.nn.ConvTranspose2d)]
    assert actual == config.weight_shapes()


def test_dilated_blocks_keep_the_weights_and_run_on_maps_smaller_than_their_dilation():
    plain = GeneratorSpec(ngf=4, n_downsample=2, n_blocks=2)
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
        GeneratorSpec(n_blocks=2, dilations=dilations)


def test_noise_z_is_dropout_in_training_only():
    torch.manual_seed(0)
    g = GlobalGenerator(GeneratorSpec(ngf=4, n_downsample=1, n_blocks=2, dropout=0.5))
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


@pytest.mark.parametrize(("term", "loss_name"), [("l1_depth", "G_l1"), ("silog", "G_silog")])
def test_without_adversarial_terms_the_discriminator_is_never_run(tmp_path, term, loss_name):
    """The masked L1 or SILog alone: one step reports that term alone, moves the generator, and never runs D."""
    from conftest import tiny_config

    from trainer.config import LossConfig, RunConfig
    from trainer.gan import Autocast, build_networks, gan_step

    config = RunConfig.model_validate(tiny_config(tmp_path))
    generator, discriminator, opt_g, opt_d = build_networks(config, torch.device("cpu"))
    before_g = [p.detach().clone() for p in generator.parameters()]
    before_d = [p.detach().clone() for p in discriminator.parameters()]
    discriminator.forward = None  # calling it would fail
    h, w = config.data.transform.size
    batch = {"rgb": torch.rand(2, 3, h, w), "depth": torch.rand(2, 1, h, w), "valid": torch.ones(2, 1, h, w)}
    loss = LossConfig(gan=0, feature_matching=0, **{term: 100})
    scaler = torch.amp.GradScaler("cpu", enabled=False)
    losses = gan_step(
        generator, discriminator, (opt_g, opt_d), scaler, GANLoss("lsgan"), loss, batch, Autocast(False, torch.bfloat16)
    )
    assert set(losses) == {loss_name} and losses[loss_name].item() > 0
    assert any(not torch.equal(a, b) for a, b in zip(before_g, generator.parameters(), strict=True))
    assert all(torch.equal(a, b) for a, b in zip(before_d, discriminator.parameters(), strict=True))
    with pytest.raises(ValueError, match="nothing would be learned"):
        LossConfig(gan=0, feature_matching=0, l1_depth=0, silog=0)


def test_the_upsamplers_that_start_free_of_the_checkerboard():
    """A flat map stays flat through a fresh shuffle stage (ICNR: each 2x2 block starts as one value) and a
    bilinear stage (both phases of every pixel pair weighted alike); a transposed convolution's uneven
    overlap makes it a checkerboard. (Only the bilinear one stays free of it in training: docs/quality.md.)"""
    from trainer.gan import init_weights
    from trainer.networks import upsampler

    torch.manual_seed(0)
    flat = torch.ones(1, 8, 16, 16)
    interior = (..., slice(4, -4), slice(4, -4))  # away from the zero padding at the border
    for kind, stays_flat in (("shuffle", True), ("bilinear", True), ("transpose", False)):
        stage = upsampler(kind, 8)
        stage.apply(init_weights)
        y = stage(flat)
        assert y.shape == (1, 4, 32, 32)
        inside = y[interior]
        assert torch.allclose(inside, inside[..., :1, :1].expand_as(inside), atol=1e-6) == stays_flat, kind


def test_silog_worked_out_by_hand():
    """Image 1: a constant error c = 0.2 on its valid pixels gives |c| sqrt(1 - lambda); image 2: errors +0.5 and
    -0.5 (mean 0) give 0.5 whatever lambda; a pixel outside the mask and an image with none valid count for
    nothing."""
    from trainer.losses import silog

    real = torch.zeros(3, 1, 1, 3)
    fake = torch.tensor([[0.2, 0.2, 9.0], [0.5, -0.5, 9.0], [9.0, 9.0, 9.0]]).reshape(3, 1, 1, 3)
    valid = torch.tensor([[1, 1, 0], [1, 1, 0], [0, 0, 0]], dtype=torch.bool).reshape(3, 1, 1, 3)
    lam = 0.85
    expected = (0.2 * (1 - lam) ** 0.5 + 0.5) / 2
    assert silog(fake, real, valid, lam).item() == pytest.approx(expected, rel=1e-5)
    # lambda 0 is the RMSE of the log error; lambda 1 forgives image 1's scale entirely.
    assert silog(fake, real, valid, 0.0).item() == pytest.approx((0.2 + 0.5) / 2, rel=1e-5)
    assert silog(fake, real, valid, 1.0).item() == pytest.approx((0.0 + 0.5) / 2, abs=1e-4)
