"""Formula (5), intrinsics bookkeeping, padding, the depth encoding and paired transforms."""

from __future__ import annotations

import numpy as np
import pytest

from model.codec import DepthEncoding, rgb_to_input
from model.config import TransformConfig
from model.data.frames import Frame
from model.data.transforms import TransformParams, apply_params, rotate_frame, rotation_matrix, sample_params
from model.geometry import KINECT_DEFAULT, POINT, Intrinsics, colours, pad_to_multiple, point_cloud, xyz


def test_point_cloud_is_formula_5():
    k = KINECT_DEFAULT
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
    frame = Frame(np.full((480, 640, 3), 100, np.uint8), np.full((480, 640), 2.0, np.float32), KINECT_DEFAULT, "f")
    out = apply_params(frame, sample_params(np.random.default_rng(1), TransformConfig(brightness=0.5), 480, 640))
    np.testing.assert_allclose(out.depth, 2.0)  # nearest-neighbour depth, untouched by colour jitter
    assert out.intrinsics.width == 320 and out.intrinsics.height == 240


def test_virtual_turn_keeps_the_scene_where_it_was():
    """After a turn R, every back-projected point is R times a point of the original scene.

    The scene is a tilted plane n . X = 2, so after the turn its points must satisfy
    (R n) . X' = 2; and pixels the old view never saw get no depth and black RGB.
    """
    h, w = 96, 128
    k = Intrinsics(110.0, 112.0, 63.2, 47.7, w, h)
    normal = np.array([0.2, -0.1, 1.0])
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(uu - k.cx) / k.fx, (vv - k.cy) / k.fy, np.ones((h, w))], -1)
    depth = (2.0 / (rays @ normal)).astype(np.float32)
    frame = Frame(np.full((h, w, 3), 200, np.uint8), depth, k, "plane")
    r = rotation_matrix(12.0, -7.0, 5.0)
    out = rotate_frame(frame, r)
    assert out.intrinsics == k and out.depth.shape == (h, w)
    valid = out.depth > 0
    assert 0.5 < valid.mean() < 0.95  # a 12° turn leaves a border the old view never saw
    points = (rays * out.depth[..., None])[valid]
    # Depth is sampled by nearest neighbour, so a point may sit up to half a pixel off the ray.
    np.testing.assert_allclose(points @ (r @ normal), 2.0, rtol=0.02)
    assert (out.rgb[~valid] == 0).all() and (out.rgb[valid] > 190).all()


def test_rotation_is_off_by_default_and_drawn_within_bounds():
    frame = Frame(
        np.full((48, 64, 3), 9, np.uint8), np.full((48, 64), 1.5, np.float32), KINECT_DEFAULT.resized(64, 48), "f"
    )
    off = TransformConfig(size=(48, 64), scale=(1.0, 1.0))
    assert sample_params(np.random.default_rng(3), off, 48, 64).rotation == (0.0, 0.0, 0.0)
    on = off.model_copy(update={"rotate_deg": 10.0})
    p_on, p_off = (
        sample_params(np.random.default_rng(3), on, 48, 64),
        sample_params(np.random.default_rng(3), off, 48, 64),
    )
    assert max(abs(a) for a in p_on.rotation) <= 10.0 and any(p_on.rotation)
    assert (p_on.flip, p_on.brightness) == (p_off.flip, p_off.brightness)  # the other draws are unchanged
    np.testing.assert_array_equal(rotate_frame(frame, np.eye(3)).depth, frame.depth)


def test_pad_to_multiple():
    img = np.arange(5 * 7 * 3).reshape(5, 7, 3)
    padded = pad_to_multiple(img, 4)
    assert padded.shape == (8, 8, 3)
    np.testing.assert_array_equal(padded[:5, :7], img)
    assert pad_to_multiple(np.zeros((2, 2, 3)), 16).shape == (16, 16, 3)  # smaller than the pad: edge mode


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


def test_zoom_depth_shows_a_zoomed_frame_as_seen_from_closer():
    """Enlarged z times beyond the crop-filling scale, a facing plane at 2 m comes to 2 / z m,
    and its back-projected x, y stay where they were; off, the zoom keeps depth (a longer lens)."""
    h, w = 96, 128
    k = Intrinsics(110.0, 112.0, 63.5, 47.5, w, h)
    frame = Frame(np.full((h, w, 3), 90, np.uint8), np.full((h, w), 2.0, np.float32), k, "wall")
    off = TransformConfig(size=(48, 64), scale=(0.75, 0.75), flip=False, brightness=0, contrast=0, saturation=0)
    on = off.model_copy(update={"zoom_depth": True})
    rng_off, rng_on = np.random.default_rng(5), np.random.default_rng(5)
    p_off, p_on = sample_params(rng_off, off, h, w), sample_params(rng_on, on, h, w)
    assert p_off.closer == 1.0 and p_on.closer == pytest.approx(1.5)  # 0.75 against the 0.5 that fills the crop
    assert p_on.crop == p_off.crop
    assert rng_on.bit_generator.state == rng_off.bit_generator.state  # no extra draw: other configs keep their stream
    np.testing.assert_allclose(apply_params(frame, p_off).depth, 2.0)
    out = apply_params(frame, p_on)
    np.testing.assert_allclose(out.depth, 2.0 / 1.5, rtol=1e-6)
    top, left = p_on.crop[:2]
    k_out = out.intrinsics
    for v2, u2 in [(0, 0), (47, 63), (20, 33)]:
        u, v = (u2 + left + 0.5) / 0.75 - 0.5, (v2 + top + 0.5) / 0.75 - 0.5  # where the pixel came from
        x_before, y_before = 2.0 * (u - k.cx) / k.fx, 2.0 * (v - k.cy) / k.fy
        x_after = out.depth[v2, u2] * (u2 - k_out.cx) / k_out.fx
        y_after = out.depth[v2, u2] * (v2 - k_out.cy) / k_out.fy
        assert (x_after, y_after) == (pytest.approx(x_before), pytest.approx(y_before))


def test_zoom_out_shows_a_shrunken_frame_inside_borders_as_seen_from_farther():
    """Below the crop-filling scale, zoom_out pads with black, depth-less borders, and with zoom_depth
    a facing plane at 2 m moves to 2 / z m for z < 1 with each pixel's x, y kept; off, the scale is
    raised to fill the crop; on, scales that fill the crop draw exactly what they drew without it."""
    h, w = 96, 128
    k = Intrinsics(110.0, 112.0, 63.5, 47.5, w, h)
    frame = Frame(np.full((h, w, 3), 90, np.uint8), np.full((h, w), 2.0, np.float32), k, "wall")
    off = TransformConfig(size=(48, 64), scale=(0.4, 0.4), flip=False, brightness=0, contrast=0, saturation=0)
    on = off.model_copy(update={"zoom_out": True, "zoom_depth": True})
    rng_off, rng_on = np.random.default_rng(7), np.random.default_rng(7)
    p_off, p_on = sample_params(rng_off, off, h, w), sample_params(rng_on, on, h, w)
    assert p_off.resize == (48, 64) and p_off.crop == (0, 0, 48, 64)  # raised to 0.5, which fills the crop
    wide = off.model_copy(update={"scale": (0.5, 0.7)})
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    p_a, p_b = sample_params(rng_a, wide, h, w), sample_params(rng_b, wide.model_copy(update={"zoom_out": True}), h, w)
    assert p_a == p_b and rng_a.bit_generator.state == rng_b.bit_generator.state
    assert p_on.resize == (39, 52) and p_on.closer == pytest.approx(0.8)
    top, left = p_on.crop[:2]
    assert -9 <= top <= 0 and -12 <= left <= 0
    out = apply_params(frame, p_on)
    assert out.depth.shape == (48, 64) and out.rgb.shape == (48, 64, 3)
    inside = out.depth > 0
    assert inside.sum() == 39 * 52  # the whole shrunken frame is kept, and only it has depth
    rows, cols = np.nonzero(inside)
    assert (rows.min(), cols.min()) == (-top, -left)
    assert (out.rgb[~inside] == 0).all() and (out.rgb[inside] == 90).all()
    np.testing.assert_allclose(out.depth[inside], 2.0 / 0.8, rtol=1e-6)
    k_out = out.intrinsics
    assert (k_out.width, k_out.height) == (64, 48)
    sx, sy = 52 / w, 39 / h  # the resize's own factors (the size is rounded up)
    for v2, u2 in [(-top, -left), (-top + 38, -left + 51), (-top + 20, -left + 33)]:
        u, v = (u2 + left + 0.5) / sx - 0.5, (v2 + top + 0.5) / sy - 0.5  # where the pixel came from
        x_before, y_before = 2.0 * (u - k.cx) / k.fx, 2.0 * (v - k.cy) / k.fy
        x_after = out.depth[v2, u2] * (u2 - k_out.cx) / k_out.fx
        y_after = out.depth[v2, u2] * (v2 - k_out.cy) / k_out.fy
        assert (x_after, y_after) == (pytest.approx(x_before), pytest.approx(y_before))
