"""Every reader on tiny files built here in that format's exact on-disk layout."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest
from conftest import SEVEN_SCENES, TUM_FRAME, save_png16
from PIL import Image
from scipy.io import savemat

from contract.errors import UserError
from recordings.frames import parse_frame_ranges, read_depth_png
from recordings.manifest import ManifestReader
from recordings.nyu import NYU_CAMERA, NyuReader
from recordings.sevenscenes import SevenScenesReader
from recordings.tum import TUM_CAMERAS, TumReader, associate
from trainer.config import DataSource
from trainer.data.sources import open_source


def _rgb(h: int, w: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def test_frame_ranges():
    assert parse_frame_ranges("0-3,7, 9-10") == [0, 1, 2, 3, 7, 9, 10]
    for bad in ("5-2", "a-b", ""):
        with pytest.raises(ValueError):
            parse_frame_ranges(bad)


def test_depth_png_marks_zero_and_65535_missing(tmp_path):
    save_png16(tmp_path / "d.png", np.array([[0, 1000, 65535, 2500]]))
    depth = read_depth_png(tmp_path / "d.png", 1000.0)
    assert depth.dtype == np.float32
    np.testing.assert_array_equal(depth, [[0.0, 1.0, 0.0, 2.5]])


def test_seven_scenes_layout(tmp_path):
    for n in range(3):
        Image.fromarray(_rgb(6, 8, n)).save(tmp_path / f"frame-{n:06d}.color.png")
        save_png16(tmp_path / f"frame-{n:06d}.depth.png", np.full((6, 8), 1000 + n))
    np.savetxt(tmp_path / "camera-intrinsics.txt", [[585, 0, 320], [0, 585, 240], [0, 0, 1]])
    reader = SevenScenesReader(tmp_path, "1-2")
    assert len(reader) == 2
    frame = reader[1]
    assert frame.name.endswith("000002")
    assert frame.rgb.shape == (6, 8, 3) and frame.rgb.dtype == np.uint8
    np.testing.assert_allclose(frame.depth, 1.002)
    # The 640x480 calibration is rescaled to this 8x6 image.
    assert frame.intrinsics.width == 8 and frame.intrinsics.fx == pytest.approx(585 * 8 / 640)
    with pytest.raises(UserError, match="missing"):
        SevenScenesReader(tmp_path, "0-5")


def test_seven_scenes_real_frames():
    reader = open_source(DataSource(format="7scenes", root=SEVEN_SCENES, frames="850-851"))
    frame = reader[0]
    assert frame.rgb.shape == (480, 640, 3) and frame.depth.shape == (480, 640)
    valid = frame.depth[frame.depth > 0]
    assert valid.min() > 0.5 and valid.max() < 4.5  # README: valid 0.80-3.98 m
    assert (frame.intrinsics.fx, frame.intrinsics.cx) == (585.0, 320.0)
    assert "non-commercial" in reader.licence


def _write_tum_list(path, entries, header):
    path.write_text(
        f"# {header}\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n# timestamp filename\n"
        + "".join(f"{t:.6f} {name}\n" for t, name in entries)
    )


def test_tum_association():
    rgb = [1.000, 1.033, 1.066, 1.200]
    depth = [1.010, 1.030, 1.095, 1.500]
    # 1.066 is 29 ms from 1.095: beyond 20 ms; 1.200 has no partner. Closest pairs win.
    assert associate(rgb, depth) == [(0, 0), (1, 1)]
    # Each depth frame is used once even when two RGB frames are near it.
    assert associate([1.0, 1.004], [1.002]) == [(0, 0)]


def test_tum_sequence(tmp_path):
    seq = tmp_path / "rgbd_dataset_freiburg1_xyz"
    (seq / "rgb").mkdir(parents=True)
    (seq / "depth").mkdir()
    rgb_entries, depth_entries = [], []
    for n in range(3):
        t = 100.0 + n * 0.1
        Image.fromarray(_rgb(6, 8, n)).save(seq / f"rgb/{t:.6f}.png")
        save_png16(seq / f"depth/{t + 0.012:.6f}.png", np.full((6, 8), 5000 * (n + 1)))
        rgb_entries.append((t, f"rgb/{t:.6f}.png"))
        depth_entries.append((t + 0.012, f"depth/{t + 0.012:.6f}.png"))
    rgb_entries.append((200.0, "rgb/missing.png"))  # no depth partner: dropped
    _write_tum_list(seq / "rgb.txt", rgb_entries, "color images")
    _write_tum_list(seq / "depth.txt", depth_entries, "depth maps")
    reader = TumReader(seq)
    assert len(reader) == 3
    frame = reader[2]
    np.testing.assert_allclose(frame.depth, 3.0)  # 15000 / 5000
    assert frame.intrinsics == TUM_CAMERAS["freiburg1"].resized(8, 6)  # the calibration, at this image size
    assert "CC BY 4.0" in reader.licence


def test_real_tum_frame_in_tum_layout(tmp_path):
    """The real fr3 frame wrapped in a TUM sequence reads back with TUM's units."""
    seq = tmp_path / "rgbd_dataset_freiburg3_office"
    (seq / "rgb").mkdir(parents=True)
    (seq / "depth").mkdir()
    shutil.copy(TUM_FRAME / "TUM_color.png", seq / "rgb/1341847980.722988.png")
    shutil.copy(TUM_FRAME / "TUM_depth.png", seq / "depth/1341847980.723020.png")
    _write_tum_list(seq / "rgb.txt", [(1341847980.722988, "rgb/1341847980.722988.png")], "color images")
    _write_tum_list(seq / "depth.txt", [(1341847980.723020, "depth/1341847980.723020.png")], "depth maps")
    frame = TumReader(seq)[0]
    raw = np.asarray(Image.open(TUM_FRAME / "TUM_depth.png")).astype(np.float32)
    assert frame.rgb.shape == (480, 640, 3)
    np.testing.assert_allclose(frame.depth, raw / 5000.0, rtol=1e-6)
    assert frame.intrinsics == TUM_CAMERAS["freiburg3"]
    valid = frame.depth[frame.depth > 0]
    assert 0.3 < np.median(valid) < 6.0  # an office seen by a Kinect


def test_nyu_labeled_mat_and_official_split(tmp_path):
    """MATLAB v7.3 layout: images (N, 3, W, H), depths (N, W, H); splits.mat 1-based."""
    n, h, w = 4, 6, 8
    images = np.stack([_rgb(h, w, i) for i in range(n)])  # (N, H, W, 3)
    depths = np.stack([np.arange(h * w, dtype=np.float32).reshape(h, w) / 10 + i for i in range(n)])
    with h5py.File(tmp_path / "nyu_depth_v2_labeled.mat", "w") as f:
        f["images"] = images.transpose(0, 3, 2, 1)  # what MATLAB's column-major order looks like
        f["depths"] = depths.transpose(0, 2, 1)
    savemat(tmp_path / "splits.mat", {"trainNdxs": np.array([[1], [3], [4]]), "testNdxs": np.array([[2]])})
    test = NyuReader(tmp_path / "nyu_depth_v2_labeled.mat", "test")
    assert len(test) == 1
    frame = test[0]
    np.testing.assert_array_equal(frame.rgb, images[1])
    np.testing.assert_allclose(frame.depth, depths[1])
    assert frame.name == "nyu/0002"
    assert frame.intrinsics.fx == pytest.approx(NYU_CAMERA.fx * w / 640)
    train = NyuReader(tmp_path / "nyu_depth_v2_labeled.mat", "train")
    assert [train[i].name for i in range(len(train))] == ["nyu/0001", "nyu/0003", "nyu/0004"]


def test_csv_manifest(tmp_path):
    Image.fromarray(_rgb(6, 8, 0)).save(tmp_path / "a.jpg")
    save_png16(tmp_path / "a.png", np.full((6, 8), 2000))
    (tmp_path / "pairs.csv").write_text("rgb,depth,depth_scale,fx,fy,cx,cy\na.jpg,a.png,1000,50,51,3.5,2.5\n")
    frame = ManifestReader(tmp_path / "pairs.csv")[0]
    np.testing.assert_allclose(frame.depth, 2.0)
    assert (frame.intrinsics.fx, frame.intrinsics.fy, frame.intrinsics.cx, frame.intrinsics.cy) == (50, 51, 3.5, 2.5)
    (tmp_path / "bad.csv").write_text("rgb,depth\na.jpg,a.png\n")
    with pytest.raises(ValueError, match="missing columns"):
        ManifestReader(tmp_path / "bad.csv")
    (tmp_path / "neg.csv").write_text("rgb,depth,depth_scale,fx,fy,cx,cy\na.jpg,a.png,1000,-5,51,3.5,2.5\n")
    with pytest.raises(ValueError, match=r"neg\.csv:2"):
        ManifestReader(tmp_path / "neg.csv")


def test_folders_source_selects_frames_and_takes_a_camera(tmp_path):
    """A training source in the folders layout: time order, a selection by glob or range, intrinsics filled in."""
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    for n in (1, 2, 10):
        Image.fromarray(_rgb(6, 8, n)).save(tmp_path / "rgb" / f"{n}.jpg")
        save_png16(tmp_path / "depth" / f"{n}.png", np.full((6, 8), 500 * n))
    camera = {"fx": 5.0, "fy": 5.0, "cx": 4.0, "cy": 3.0}
    reader = open_source(DataSource(format="folders", root=tmp_path, frames="1-2", camera=camera))
    assert [reader[i].name for i in range(len(reader))] == [f"{tmp_path.name}/2", f"{tmp_path.name}/10"]
    np.testing.assert_allclose(reader[1].depth, 5.0)  # millimetres unless a depth_scale says otherwise
    assert reader[0].intrinsics.fx == 5.0 and reader[0].intrinsics.width == 8
    assert len(open_source(DataSource(format="folders", root=tmp_path, frames="1*", camera=camera))) == 2
    with pytest.raises(ValueError, match=r"no camera intrinsics"):
        open_source(DataSource(format="folders", root=tmp_path))
    (tmp_path / "intrinsics.json").write_text('{"fx": 6, "fy": 6, "cx": 4, "cy": 3, "depth_scale": 5000}')
    own = open_source(DataSource(format="folders", root=tmp_path, frames="0"))
    assert own[0].intrinsics.fx == 6.0 and own[0].depth[0, 0] == pytest.approx(0.1)
    with pytest.raises(ValueError, match="match no frame name"):
        open_source(DataSource(format="folders", root=tmp_path, frames="test*"))
