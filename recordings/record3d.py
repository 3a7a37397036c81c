"""Record3D ``.r3d`` exports (iPhone and iPad LiDAR) as colour/depth pairs in the colour camera, written out.

An ``.r3d`` file is a zip holding:

- ``metadata``: JSON with ``K`` (the colour camera's 3x3 intrinsics, column-major), ``w`` and
  ``h`` (the photos' size), ``dw`` and ``dh`` (the depth maps'), and ``fps``;
- ``rgbd/N.jpg``: frame N's photo;
- ``rgbd/N.depth``: its depth, LZFSE-compressed float32 metres, ``dh`` x ``dw``;
- ``rgbd/N.conf``: its confidence (0, 1 or 2 per depth pixel), LZFSE-compressed uint8.

Depth covers the same view as the photo at a coarser grid, so it is upsampled as a Stray Scanner
recording's is, by the same writer (``recordings.pair_writer``): at the size fit trains at, with
the intrinsics scaled to match, and of a long recording an evenly spread cap of frames.
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
from recordings.folders import CameraFile
from recordings.frames import PairsReader
from recordings.pair_writer import PairWriter, written_pairs
from recordings.phone_options import PhoneOptions


def is_record3d(path: Path) -> bool:
    return Path(path).is_file() and Path(path).suffix.lower() == ".r3d"


def read_record3d(path: Path, out: Path, options: PhoneOptions | None = None) -> PairsReader:
    """The kept frames, written under ``out`` as colour JPEG and 16-bit millimetre PNG."""
    path, out = Path(path), Path(out)
    try:
        with zipfile.ZipFile(path) as archive:
            return _read(archive, path, out, options or PhoneOptions())
    except (zipfile.BadZipFile, EOFError) as e:
        raise UserError(f"{path}: not a complete .r3d (zip) file: {e}") from None


def _read(archive: zipfile.ZipFile, path: Path, out: Path, options: PhoneOptions) -> PairsReader:
    metadata = _metadata(archive, path)
    width, height, depth_size = metadata["w"], metadata["h"], (metadata["dh"], metadata["dw"])
    writer = PairWriter(out, width, height)
    recorded = CameraFile.of(_intrinsics(path, metadata["K"], width, height))
    camera = writer.camera(recorded.merged(options.camera).intrinsics(width, height, path))
    names = {info.filename for info in archive.infolist()}
    numbers = sorted(int(n[5:-4]) for n in names if n.startswith("rgbd/") and n.endswith(".jpg") and n[5:-4].isdigit())
    if not numbers:
        raise UserError(f"{path}: no rgbd/N.jpg photos inside")
    pairs, skipped, kept = [], [], []
    fps = float(metadata.get("fps") or 0) or None
    wanted = options.kept(numbers)
    for number in wanted:
        if f"rgbd/{number}.depth" not in names:
            skipped.append((str(number), "no rgbd/N.depth beside the photo"))
            continue
        try:
            with Image.open(io.BytesIO(archive.read(f"rgbd/{number}.jpg"))) as im:
                photo = im.convert("RGB")
        except (OSError, ValueError, SyntaxError):
            skipped.append((str(number), f"damaged: rgbd/{number}.jpg is not a readable JPEG"))
            continue
        depth = _lzfse(archive, path, f"rgbd/{number}.depth", np.float32, depth_size)
        depth = np.where(np.isfinite(depth), depth, 0).astype(np.float32)
        if f"rgbd/{number}.conf" in names:
            confidence = _lzfse(archive, path, f"rgbd/{number}.conf", np.uint8, depth_size)
            depth = np.where(confidence >= options.min_confidence, depth, 0).astype(np.float32)
        kept.append(float((depth > 0).mean()))
        pairs.append(writer.write(f"{number / fps:.6f}" if fps else f"{number:06d}", photo, depth))
    notes = [
        f"record3d: {len(numbers)} frames, photos {width}x{height} written at {camera.width}x{camera.height}, "
        f"depth {depth_size[1]}x{depth_size[0]}",
        options.note(len(numbers), len(wanted)),
        f"depth: confidence {options.min_confidence} and up kept, {100 * float(np.mean(kept or [0])):.0f}% of depth "
        "pixels; upsampled without blending across depth steps",
    ]
    return written_pairs(path.stem, pairs, camera, skipped, notes)


def _metadata(archive: zipfile.ZipFile, path: Path) -> dict:
    try:
        metadata = json.loads(archive.read("metadata"))
    except KeyError:
        raise UserError(f"{path}: no metadata inside; not a Record3D export") from None
    except json.JSONDecodeError as e:
        raise UserError(f"{path}: its metadata is not JSON: {e}") from None
    if not isinstance(metadata, dict):
        raise UserError(f"{path}: its metadata is not a JSON object")
    missing = [key for key in ("K", "w", "h", "dw", "dh") if key not in metadata]
    if missing:
        raise UserError(f"{path}: its metadata lacks {', '.join(missing)}")
    for key in ("w", "h", "dw", "dh"):
        value = metadata[key]
        if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
            raise UserError(f"{path}: its metadata's {key} is {value!r}, not a positive whole number of pixels")
    return metadata


def _intrinsics(path: Path, k: object, width: int, height: int) -> Intrinsics:
    """The metadata's ``K`` (9 numbers, column-major) as the photos' camera; one line naming the file if malformed."""
    try:
        matrix = np.asarray(k, dtype=np.float64).reshape(3, 3).T  # stored column-major
    except (TypeError, ValueError):
        raise UserError(f"{path}: its metadata's K is {str(k)[:80]}, not 9 numbers (a 3x3 matrix)") from None
    if not (np.isfinite(matrix).all() and matrix[0, 0] > 0 and matrix[1, 1] > 0):
        raise UserError(f"{path}: its metadata's K has no positive focal lengths: {matrix.T.ravel().tolist()}")
    return Intrinsics(matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], width, height)


def _lzfse(archive: zipfile.ZipFile, path: Path, member: str, dtype: type, shape: tuple[int, int]) -> np.ndarray:
    import lzfse

    try:
        values = np.frombuffer(lzfse.decompress(archive.read(member)), dtype=dtype)
    except lzfse.error:
        raise UserError(f"{path}: damaged: {member}'s LZFSE data cannot be decompressed") from None
    except zipfile.BadZipFile as e:
        why = "fails its checksum" if "CRC" in str(e) else "is not a readable zip member"
        raise UserError(f"{path}: damaged: {member} {why}") from None
    except EOFError:
        raise UserError(f"{path}: damaged: {member} is cut short") from None
    if values.size != shape[0] * shape[1]:
        raise UserError(f"{path}: {member} holds {values.size} values, not {shape[1]}x{shape[0]}")
    return values.reshape(shape)
