"""The colour-weighted median that refines a prediction at inference (model.refine)."""

from __future__ import annotations

import itertools

import pytest
import torch
import torch.nn.functional as F

from model.config import GeneratorConfig
from model.networks import GlobalGenerator
from model.refine import ColourGuidedUpsample, ColourWeightedMedian, sorting_network


@pytest.mark.parametrize("n", [1, 2, 3, 5, 9, 12])
def test_the_sorting_network_sorts_every_zero_one_input(n):
    """By the zero-one principle, a comparator network that sorts all 2^n 0/1 inputs sorts everything."""
    pairs = sorting_network(n)
    for bits in itertools.product((0, 1), repeat=n):
        values = list(bits)
        for low, high in pairs:
            if values[low] > values[high]:
                values[low], values[high] = values[high], values[low]
        assert values == sorted(bits)


def test_the_sorting_network_sorts_the_window_sizes_in_use():
    generator = torch.Generator().manual_seed(0)
    for n in (9, 25, 49):
        values = torch.rand(n, 200, generator=generator)
        rows = list(values)
        for low, high in sorting_network(n):
            rows[low], rows[high] = torch.minimum(rows[low], rows[high]), torch.maximum(rows[low], rows[high])
        torch.testing.assert_close(torch.stack(rows), values.sort(0).values, rtol=0, atol=0)


def _brute_force(depth, rgb, radius, sigma, spacing):
    """The definition, pixel by pixel: sort the window's (depth, weight) pairs, walk to half the weight."""
    reach = radius * spacing
    depth_pad = F.pad(depth, [reach] * 4, mode="replicate")[0, 0]
    rgb_pad = F.pad(rgb, [reach] * 4, mode="replicate")[0]
    out = torch.empty_like(depth)
    for y, x in itertools.product(range(depth.shape[2]), range(depth.shape[3])):
        taps = []
        for i, j in itertools.product(range(2 * radius + 1), repeat=2):
            q = y + i * spacing, x + j * spacing
            difference = rgb_pad[:, q[0], q[1]] - rgb[0, :, y, x]
            taps.append((float(depth_pad[q]), float(torch.exp(-(difference**2).sum() / (2 * sigma**2)))))
        taps.sort()
        total, cumulative = sum(w for _, w in taps), 0.0
        for value, weight in taps:
            cumulative += weight
            if cumulative >= 0.5 * total:
                out[0, 0, y, x] = value
                break
    return out


@pytest.mark.parametrize("radius,spacing", [(1, 1), (2, 2)])
def test_the_median_is_the_weighted_median_by_definition(radius, spacing):
    generator = torch.Generator().manual_seed(1)
    depth = torch.rand(1, 1, 9, 11, generator=generator)
    rgb = torch.rand(1, 3, 9, 11, generator=generator) * 2 - 1
    median = ColourWeightedMedian(radius, 0.3, spacing)
    expected = _brute_force(depth, rgb, radius, 0.3, spacing)
    torch.testing.assert_close(median(depth, rgb), expected, rtol=0, atol=1e-6)
    torch.testing.assert_close(torch.jit.script(median)(depth, rgb), expected, rtol=0, atol=1e-6)


def test_a_blurred_step_snaps_to_the_colour_edge_and_stays_blurred_without_one():
    """Depth ramps from 0 to 1 over columns 18-21; the photo changes colour between 19 and 20."""
    depth = torch.zeros(1, 1, 8, 40)
    depth[..., 18:22] = torch.tensor([0.2, 0.4, 0.6, 0.8])
    depth[..., 22:] = 1.0
    edge = torch.full((1, 3, 8, 40), -0.5)
    edge[..., 20:] = 0.5
    snapped = ColourWeightedMedian(2, 0.1, 2)(depth, edge)[0, 0, 4]
    assert snapped[:20].tolist() == [0.0] * 20 and snapped[20:].tolist() == [1.0] * 20
    # With no colour edge to follow it is a plain median, which keeps a straight ramp.
    plain = ColourWeightedMedian(2, 0.1, 2)(depth, torch.zeros(1, 3, 8, 40))[0, 0, 4]
    torch.testing.assert_close(plain[16:24], depth[0, 0, 4, 16:24])


def test_radius_zero_is_the_identity():
    depth = torch.rand(1, 1, 6, 7)
    assert ColourWeightedMedian(0, 0.1)(depth, torch.rand(1, 3, 6, 7)) is depth


def test_the_generator_refines_at_inference_only_with_the_same_weights():
    plain_config = GeneratorConfig(ngf=4, n_downsample=2, n_blocks=1, work_scale=2)
    torch.manual_seed(0)
    plain = GlobalGenerator(plain_config).eval()
    refined = GlobalGenerator(plain_config.run_as({"median_radius": 1, "median_sigma": 0.2})).eval()
    assert refined.load_state_dict(plain.state_dict()).missing_keys == []  # no weights of its own
    x = torch.rand(1, 3, 32, 48) * 2 - 1
    with torch.inference_mode():
        small = F.avg_pool2d(x, 2)
        # Training's path (at the working scale) is untouched; inference refines before upsampling.
        torch.testing.assert_close(refined(small, at_working_scale=True), plain(small, at_working_scale=True))
        expected = F.interpolate(
            ColourWeightedMedian(1, 0.2)(plain(small, at_working_scale=True), small), scale_factor=2.0, mode="bilinear"
        )
        torch.testing.assert_close(refined(x), expected)
        assert not torch.equal(refined(x), plain(x))


def test_only_inference_settings_change_after_training():
    config = GeneratorConfig(ngf=4, n_downsample=2, n_blocks=1)
    assert config.run_as({"median_radius": 2}).median_radius == 2
    with pytest.raises(ValueError, match="shape the weights"):
        config.run_as({"ngf": 8})
    with pytest.raises(ValueError, match="median_radius"):
        config.run_as({"median_radius": -1})
    assert config.run_as({"upsample_sigma": 0.2}).upsample_sigma == 0.2
    with pytest.raises(ValueError, match="upsample_sigma"):
        config.run_as({"upsample_sigma": -0.1})


@pytest.mark.parametrize("scale", [2, 3])
def test_guided_upsampling_with_a_wide_colour_scale_is_bilinear_interpolation(scale):
    """Every colour weighs alike, so only the taps' tents are left: the sub-pixel phases and borders match."""
    generator = torch.Generator().manual_seed(1)
    depth = torch.rand(2, 1, 5, 7, generator=generator)
    rgb = torch.rand(2, 3, 5 * scale, 7 * scale, generator=generator) * 2 - 1
    upsampled = ColourGuidedUpsample(scale, 1e4)(depth, F.avg_pool2d(rgb, scale), rgb)
    bilinear = F.interpolate(depth, scale_factor=float(scale), mode="bilinear", align_corners=False)
    torch.testing.assert_close(upsampled, bilinear, rtol=0, atol=1e-6)


def test_guided_upsampling_puts_a_step_on_the_photo_s_edge():
    """A step between working-scale pixels 1 and 2: bilinear makes a ramp, the colours place it."""
    depth = torch.tensor([0.0, 0.0, 1.0, 1.0]).view(1, 1, 1, 4).repeat(1, 1, 2, 1)
    rgb = torch.tensor([-1.0] * 4 + [1.0] * 4).view(1, 1, 1, 8).repeat(1, 3, 4, 1)  # dark left half, light right
    small = F.avg_pool2d(rgb, 2)
    guided = ColourGuidedUpsample(2, 0.1)(depth, small, rgb)
    expected = torch.tensor([0.0] * 4 + [1.0] * 4).expand(1, 1, 4, 8)
    torch.testing.assert_close(guided, expected, rtol=0, atol=1e-6)
    ramp = ColourGuidedUpsample(2, 0.0)(depth, small, rgb)  # sigma 0: plain bilinear
    assert ramp[0, 0, 0].tolist() == [0.0, 0.0, 0.0, 0.25, 0.75, 1.0, 1.0, 1.0]


def test_guided_upsampling_never_divides_by_an_underflowed_weight():
    """Colours far from every tap's would underflow exp(); weights are measured from the closest colour."""
    depth = torch.tensor([[[[0.2, 0.8]]]])
    small = torch.tensor([-1.0, 1.0]).view(1, 1, 1, 2).expand(1, 3, 1, 2)
    rgb = torch.full((1, 3, 2, 4), 1.0)
    rgb[..., 1] = -0.9  # closest to the left tap, by far from both at sigma 0.01
    out = ColourGuidedUpsample(2, 0.01)(depth, small, rgb)
    assert torch.isfinite(out).all()
    assert out[0, 0, 0, 1].item() == pytest.approx(0.2)


def test_the_generator_upsamples_by_colour_at_inference_only_with_the_same_weights():
    plain_config = GeneratorConfig(ngf=4, n_downsample=2, n_blocks=1, work_scale=2, median_radius=1)
    torch.manual_seed(0)
    plain = GlobalGenerator(plain_config).eval()
    guided = GlobalGenerator(plain_config.run_as({"upsample_sigma": 0.2})).eval()
    assert guided.load_state_dict(plain.state_dict()).missing_keys == []
    x = torch.rand(1, 3, 32, 48) * 2 - 1
    with torch.inference_mode():
        small = F.avg_pool2d(x, 2)
        torch.testing.assert_close(guided(small, at_working_scale=True), plain(small, at_working_scale=True))
        refined = ColourWeightedMedian(1, 0.1)(plain(small, at_working_scale=True), small)
        torch.testing.assert_close(guided(x), ColourGuidedUpsample(2, 0.2)(refined, small, x))
        torch.testing.assert_close(plain(x), F.interpolate(refined, scale_factor=2.0, mode="bilinear"))
        assert not torch.equal(guided(x), plain(x))
