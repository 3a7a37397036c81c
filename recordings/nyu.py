"""NYU Depth V2 labeled set: nyu_depth_v2_labeled.mat (MATLAB v7.3 = HDF5) + splits.mat.

MATLAB stores arrays column-major, so h5py sees images as (N, 3, W, H) and
depths as (N, W, H); each frame is transposed back to H x W here. The official
795/654 split lives in the toolbox's splits.mat (MATLAB v5, 1-based indices:
``trainNdxs`` and ``testNdxs``), read with SciPy.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
from scipy.io import loadmat

from contract.errors import UserError
from contract.geometry import Intrinsics
from recordings.frames import Frame

LICENCE = "NYU Depth V2 (Silberman et al., ECCV 2012): no licence stated; research use, cite the paper"
#: The RGB camera calibration from the NYU toolbox (camera_params.m).
NYU_CAMERA = Intrinsics(518.8579, 519.4696, 325.5824, 253.7362, 640, 480)


def read_split(splits_file: Path, split: str) -> list[int]:
    key = {"train": "trainNdxs", "test": "testNdxs"}[split]
    table = loadmat(splits_file)
    if key not in table:
        raise UserError(f"{splits_file}: no {key!r} array")
    return [int(i) - 1 for i in np.asarray(table[key]).ravel()]


class NyuReader:
    """Frames of the labeled .mat; ``split`` 'train'/'test' uses the official indices."""

    def __init__(self, mat_path: Path, split: str = "all", splits_file: Path | None = None):
        self.path = Path(mat_path)
        self.name = f"nyu-depth-v2-{split}"
        self.licence = LICENCE
        with h5py.File(self.path, "r") as f:
            for key in ("images", "depths"):
                if key not in f:
                    raise UserError(f"{self.path}: no {key!r} dataset")
            count = f["images"].shape[0]
        if split == "all":
            self.indices = list(range(count))
        else:
            self.indices = read_split(Path(splits_file or self.path.with_name("splits.mat")), split)
        if any(not 0 <= i < count for i in self.indices):
            raise UserError(f"{self.path}: split indices outside 1..{count}")
        self._file: h5py.File | None = None  # opened lazily: h5py handles do not survive fork

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, index: int) -> Frame:
        if self._file is None:
            self._file = h5py.File(self.path, "r")
        i = self.indices[index]
        rgb = np.ascontiguousarray(np.asarray(self._file["images"][i]).transpose(2, 1, 0), dtype=np.uint8)
        depth = np.ascontiguousarray(np.asarray(self._file["depths"][i], dtype=np.float32).T)
        depth[~np.isfinite(depth) | (depth < 0)] = 0.0
        h, w = depth.shape
        intrinsics = NYU_CAMERA if (w, h) == (640, 480) else NYU_CAMERA.resized(w, h)
        return Frame(rgb, depth, intrinsics, f"nyu/{i + 1:04d}")

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_file": None}
