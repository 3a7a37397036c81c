"""Record3D ``.r3d`` exports (iPhone and iPad LiDAR) as colour/depth pairs in the colour camera, written out.

An ``.r3d`` file is a zip holding:

- ``metadata``: JSON with ``K`` (the colour camera's 3x3 intrinsics, column-major), ``w`` and
  ``h`` (the photos' size), ``dw`` and ``dh`` (the depth maps'), and ``fps``;
- ``rgbd/N.jpg``: frame N's photo;
- ``rgbd/N.depth``: its depth, LZFSE-compressed float32 metres, ``dh`` x ``dw``;
- ``rgbd/N.conf``: its confidence (0, 1 or 2 per depth pixel), LZFSE-compressed uint8.

Depth covers the same view as the photo at a coarser grid, so it is upsampled as a Stray Scanner
recording's is (``trainer.registration.upsample_depth``), and photos are written at most
1280x960, with the intrinsics scaled to match.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image

from contract.errors import UserError
from contract.geometry import Intrinsics
from trainer.data.frames import PairsReader, written_pairs
from trainer.data.strayscanner import DEFAULT_MIN_CONFIDENCE, MAX_WRITTEN_PIXELS
from trainer.registration import upsample_depth


def is_record3d(path: Path) -> bool:
    return Path(path).is_file() and Path(path).suffix.lower() == ".r3d"


def read_record3d(path: Path, out: Path, every: int = 1, min_confidence: int = DEFAULT_MIN_CONFIDENCE) -> PairsReader:
    """Every ``every``-th frame, written under ``out`` as colour JPEG and 16-bit millimetre PNG."""
    path, out = Path(path), Path(out)
    try:
        with zipfile.ZipFile(path) as archive:
            return _read(archive, path, out, every, min_confidence)
    except (zipfile.BadZipFile, EOFError) as e:
        raise UserError(f"{path}: not a complete .r3d (zip) file: {e}") from None


def _read(archive: zipfile.ZipFile, path: Path, out: Path, every: int, min_confidence: int) -> PairsReader:
    metadata = _metadata(archive, path)
    k = np.asarray(metadata["K"], dtype=np.float64).reshape(3, 3).T  # stored column-major
    width, height, depth_size = int(metadata["w"]), int(metadata["h"]), (int(metadata["dh"]), int(metadata["dw"]))
    scale = min(1.0, float(np.sqrt(MAX_WRITTEN_PIXELS / (width * height))))
    size = (round(width * scale), round(height * scale))
    camera = Intrinsics(k[0, 0], k[1, 1], k[0, 2], k[1, 2], width, height).resized(*size)
    names = {info.filename for info in archive.infolist()}
    numbers = sorted(int(n[5:-4]) for n in names if n.startswith("rgbd/") and n.endswith(".jpg") and n[5:-4].isdigit())
    if not numbers:
        raise UserError(f"{path}: no rgbd/N.jpg photos inside")
    (out / "color").mkdir(parents=True, exist_ok=True)
    (out / "depth").mkdir(parents=True, exist_ok=True)
    pairs, skipped, kept = [], [], []
    fps = float(metadata.get("fps") or 0) or None
    for number in numbers[:: max(1, every)]:
        if f"rgbd/{number}.depth" not in names:
            skipped.append((str(number), "no rgbd/N.depth beside the photo"))
            continue
        with Image.open(io.BytesIO(archive.read(f"rgbd/{number}.jpg"))) as im:
            photo = np.asarray(im.convert("RGB").resize(size, Image.BILINEAR))
        depth = _lzfse(archive, path, f"rgbd/{number}.depth", np.float32, depth_size)
        depth = np.where(np.isfinite(depth), depth, 0).astype(np.float32)
        if f"rgbd/{number}.conf" in names:
            confidence = _lzfse(archive, path, f"rgbd/{number}.conf", np.uint8, depth_size)
            depth = np.where(confidence >= min_confidence, depth, 0).astype(np.float32)
        kept.append(float((depth > 0).mean()))
        name = f"{number / fps:.6f}" if fps else f"{number:06d}"
        millimetres = np.clip(np.rint(upsample_depth(depth, photo) * 1000.0), 0, 65535).astype(np.uint16)
        Image.fromarray(photo).save(out / "color" / f"{name}.jpg", quality=95)
        Image.fromarray(millimetres).save(out / "depth" / f"{name}.png")
        pairs.append((name, out / "color" / f"{name}.jpg", out / "depth" / f"{name}.png"))
    notes = [
        f"record3d: {len(numbers)} frames, photos {width}x{height} written at {size[0]}x{size[1]}, depth "
        f"{depth_size[1]}x{depth_size[0]}" + (f", every {every}th frame" if every > 1 else ""),
        f"depth: confidence {min_confidence} and up kept, {100 * float(np.mean(kept or [0])):.0f}% of depth pixels; "
        "upsampled without blending across depth steps",
    ]
    return written_pairs(path.stem, pairs, camera, skipped, notes)


def _metadata(archive: zipfile.ZipFile, path: Path) -> dict:
    try:
        metadata = json.loads(archive.read("metadata"))
    except KeyError:
        raise UserError(f"{path}: no metadata inside; not a Record3D export") from None
    except json.JSONDecodeError as e:
        raise UserError(f"{path}: its metadata is not JSON: {e}") from None
    missing = [key for key in ("K", "w", "h", "dw", "dh") if key not in metadata]
    if missing:
        raise UserError(f"{path}: its metadata lacks {', '.join(missing)}")
    return metadata


def _lzfse(archive: zipfile.ZipFile, path: Path, member: str, dtype: type, shape: tuple[int, int]) -> np.ndarray:
    import lzfse

    try:
        values = np.frombuffer(lzfse.decompress(archive.read(member)), dtype=dtype)
    except (lzfse.error, zipfile.BadZipFile, EOFError) as e:
        raise UserError(f"{path}: {member} is damaged: {e}") from None
    if values.size != shape[0] * shape[1]:
        raise UserError(f"{path}: {member} holds {values.size} values, not {shape[1]}x{shape[0]}")
    return values.reshape(shape)
