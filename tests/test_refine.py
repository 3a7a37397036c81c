"""The colour-weighted median that refines a prediction at inference (trainer.refine)."""

from __future__ import annotations

import itertools

import pytest
import torch
import torch.nn.functional as F

from contract.spec import GeneratorSpec, InferenceSettings, parse_inference_options
from trainer.inference import InferenceGraph
from trainer.networks import GlobalGenerator
from trainer.refine import ColourWeightedMedian, sorting_network


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


def test_the_graph_refines_at_inference_only_with_the_same_weights():
    torch.manual_seed(0)
    generator = GlobalGenerator(GeneratorSpec(ngf=4, n_downsample=2, n_blocks=1, work_scale=2)).eval()
    plain = InferenceGraph(generator, InferenceSettings()).eval()
    refined = InferenceGraph(generator, InferenceSettings(median_radius=1, median_sigma=0.2)).eval()
    assert refined.state_dict().keys() == plain.state_dict().keys()  # no weights of its own
    x = torch.rand(1, 3, 32, 48) * 2 - 1
    with torch.inference_mode():
        small = F.avg_pool2d(x, 2)
        expected = F.interpolate(
            ColourWeightedMedian(1, 0.2)(generator(small), small), scale_factor=2.0, mode="bilinear"
        )
        torch.testing.assert_close(refined(x), expected)
        assert not torch.equal(refined(x), plain(x))
        torch.testing.assert_close(torch.jit.script(refined)(x), refined(x))


def test_inference_options_are_checked_by_name_and_value():
    assert parse_inference_options(["median_radius=2", "median_sigma=0.2"]) == {"median_radius": 2, "median_sigma": 0.2}
    assert InferenceSettings().updated({"median_spacing": 4}).median_spacing == 4
    with pytest.raises(ValueError, match="expected KEY=VALUE with KEY one of"):
        parse_inference_options(["ngf=8"])  # shapes the weights: not an inference setting
    with pytest.raises(ValueError, match="median_radius"):
        parse_inference_options(["median_radius=-1"])
    with pytest.raises(ValueError, match="KEY=VALUE"):
        parse_inference_options(["median_radius"])
