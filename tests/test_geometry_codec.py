"""Formula (5), intrinsics bookkeeping, padding, the depth encoding and paired transforms."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import KINECT

from contract.codec import DepthEncoding, rgb_to_input
from contract.geometry import POINT, Intrinsics, colours, pad_to_multiple, point_cloud, xyz
from recordings.frames import Frame
from trainer.config import TransformConfig
from trainer.data.transforms import TransformParams, apply_params, crop_size, sample_params


def test_point_cloud_is_formula_5():
    k = KINECT
    depth = np.full((k.height, k.width), 2.0, dtype=np.float32)
    rgb = np.zeros((k.height, k.width, 3), np.uint8)
    rgb[400, 100] = (10, 20, 30)
    cloud = point_cloud(depth, rgb, k)
    u, v = 100, 400
    assert cloud.dtype == POINT and len(cloud) == k.width * k.height
    np.testing.assert_allclose(
        xyz(cloud)[v * k.width + u], [2.0 * (u - 320.1) / 535.4, 2.0 * (v - 247.6) / 539.2, 2.0], rtol=1e-6
    )
    assert colours(cloud)[v * k.width + u].tolist() == [10, 20, 30]


def test_point_cloud_drops_invalid_and_clips():
    k = Intrinsics(10, 10, 1.5, 1.5, 4, 4)
    depth = np.array([[0, 1, 2, 3], [4, 5, np.nan, 7], [1, 1, 1, 1], [1, 1, 1, 1]], dtype=np.float32)
    rgb = np.arange(48, dtype=np.uint8).reshape(4, 4, 3)
    cloud = point_cloud(depth, rgb, k, min_depth=1.5, max_depth=5)
    np.testing.assert_allclose(sorted(cloud["z"]), [2, 3, 4, 5])
    assert colours(cloud)[cloud["z"] == 2].tolist() == [rgb[0, 2].tolist()]
    depth[1, 3] = np.inf
    assert 7 not in point_cloud(depth, rgb, k)["z"] and not np.isinf(point_cloud(depth, rgb, k)["z"]).any()
    assert len(point_cloud(depth, rgb, k, stride=2)) == 3  # (0,0) is missing; (0,2), (2,0), (2,2) remain


def test_resize_keeps_rays():
    """A pixel centre and its image after a 2x resize see the same ray."""
    k = Intrinsics(500, 500, 319.5, 239.5, 640, 480)
    r = k.resized(1280, 960)
    u = 100.0
    u2 = (u + 0.5) * 2 - 0.5
    assert (u2 - r.cx) / r.fx == pytest.approx((u - k.cx) / k.fx)
    assert (r.fx, r.fy) == (1000, 1000)


def test_paired_crop_and_flip_keep_rgb_depth_and_rays_aligned():
    h, w = 48, 64
    k = Intrinsics(60.0, 62.0, 30.2, 22.7, w, h)
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    rgb = np.stack([uu, vv, np.zeros_like(uu)], -1).astype(np.uint8)  # each pixel knows where it was
    depth = (1.0 + uu / 100 + vv / 1000).astype(np.float32)
    frame = Frame(rgb, depth, k, "grid")
    params = TransformParams(resize=(h, w), crop=(5, 9, 32, 40), flip=True, brightness=1, contrast=1, saturation=1)
    out = apply_params(frame, params)
    assert out.rgb.shape == (32, 40, 3) and out.depth.shape == (32, 40)
    for v2, u2 in [(0, 0), (31, 39), (10, 17)]:
        u, v = int(out.rgb[v2, u2, 0]), int(out.rgb[v2, u2, 1])
        assert out.depth[v2, u2] == depth[v, u]  # depth moved with the RGB
        ray_before = ((u - k.cx) / k.fx, (v - k.cy) / k.fy)
        ray_after = ((u2 - out.intrinsics.cx) / out.intrinsics.fx, (v2 - out.intrinsics.cy) / out.intrinsics.fy)
        assert ray_after[0] == pytest.approx(-ray_before[0])  # a flip mirrors the scene
        assert ray_after[1] == pytest.approx(ray_before[1])


def test_sampled_params_cover_the_crop_and_jitter_only_rgb():
    config = TransformConfig(size=(96, 128), scale=(0.1, 0.2))
    rng = np.random.default_rng(0)
    for _ in range(20):
        p = sample_params(rng, config, 480, 640)
        top, left, ch, cw = p.crop
        assert (ch, cw) == (96, 128)
        assert top + ch <= p.resize[0] and left + cw <= p.resize[1]
    frame = Frame(np.full((480, 640, 3), 100, np.uint8), np.full((480, 640), 2.0, np.float32), KINECT, "f")
    out = apply_params(frame, sample_params(np.random.default_rng(1), TransformConfig(brightness=0.5), 480, 640))
    np.testing.assert_allclose(out.depth, 2.0)  # nearest-neighbour depth, untouched by colour jitter
    assert out.intrinsics.width == 320 and out.intrinsics.height == 240


def test_pad_to_multiple():
    img = np.arange(5 * 7 * 3).reshape(5, 7, 3)
    padded = pad_to_multiple(img, 4)
    assert padded.shape == (8, 8, 3)
    np.testing.assert_array_equal(padded[:5, :7], img)
    # Smaller than the pad: edge mode, and never under two grid cells a side (the generator's innermost
    # reflection padding needs two; ONNX Runtime refuses one).
    assert pad_to_multiple(np.zeros((2, 2, 3)), 16).shape == (32, 32, 3)
    assert pad_to_multiple(np.zeros((1, 40, 3)), 16).shape == (32, 48, 3)


@pytest.mark.parametrize("kind", ["log", "linear"])
def test_depth_encoding_round_trip(kind):
    enc = DepthEncoding(kind=kind, min_m=0.25, max_m=10.0)
    d = np.array([0.25, 0.8, 1.81, 3.98, 10.0], dtype=np.float32)
    y = enc.encode(d)
    assert y.min() == pytest.approx(-1) and y.max() == pytest.approx(1)
    np.testing.assert_allclose(enc.decode(y), d, rtol=1e-5)
    np.testing.assert_allclose(enc.decode(np.array([-5.0, 5.0])), [0.25, 10.0])  # clipped to the range
    with pytest.raises(ValueError):
        DepthEncoding(min_m=5, max_m=1)


def test_rgb_to_input_range_and_layout():
    x = rgb_to_input(np.array([[[0, 255, 127]]], dtype=np.uint8))
    assert x.shape == (1, 3, 1, 1) and x.dtype == np.float32
    np.testing.assert_allclose(x.ravel(), [-1.0, 1.0, 127 / 127.5 - 1], rtol=1e-6)


def test_mixed_extent_batches_are_narrower_views_at_the_same_scale_on_the_network_grid():
    """``extent`` crops a narrower view without resampling it (a longer lens at the training focal length),
    whole frames in ``whole_share`` of the batches, every size a multiple of the network's grid."""
    config = TransformConfig(size=(240, 320), scale=(0.5, 0.5), extent=(0.5, 1.0), whole_share=0.5)
    sizes = [crop_size(np.random.default_rng([0, batch, 1]), config, 8) for batch in range(200)]
    assert 0.35 < sum(s == (240, 320) for s in sizes) / len(sizes) < 0.65
    assert all(h % 8 == 0 and w % 8 == 0 and 120 <= h <= 240 and 160 <= w <= 320 for h, w in sizes)
    assert min(h for h, _ in sizes) < 140
    frame = Frame(np.zeros((480, 640, 3), np.uint8), np.full((480, 640), 2.0, np.float32), KINECT, "f")
    out = apply_params(frame, sample_params(np.random.default_rng(2), config, 480, 640, (120, 160)))
    assert out.depth.shape == (120, 160)
    assert out.intrinsics.fx == pytest.approx(KINECT.fx * 0.5)  # the scale of a whole frame: only the view narrows
    with pytest.raises(ValueError, match="extent"):
        TransformConfig(extent=(0.1, 1.0))
