"""Shared fixtures: paths to the real data, tiny run configs, a tiny trained checkpoint."""

from __future__ import annotations

import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from contract.geometry import Intrinsics

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
SEVEN_SCENES = DATA / "7scenes-redkitchen"
TUM_FRAME = DATA / "tum-fr3-office"
#: How closely one model's metrics, computed along two routes (another process, batch or entry point), must
#: agree. Not bit for bit: oneDNN picks its float32 kernels by CPU (AMX, AVX-512, AVX2) and their sums round
#: differently, about 1e-6 relative to a mean, and a pixel sitting on a δ threshold may land on either side,
#: moving δ by 1/N (2e-6 for two 640x480 frames). A real difference in scoring moves them by far more.
FLOAT32_METRICS: dict[str, float] = {"rel": 1e-4, "abs": 2e-5}
#: The Kinect calibration the paper uses (TUM fr3 defaults), at 640x480.
KINECT = Intrinsics(fx=535.4, fy=539.2, cx=320.1, cy=247.6, width=640, height=480)


def tiny_config(out_dir: Path, **sections) -> dict:
    """A run small enough for CI: 4 real 7-Scenes frames at 96x128, a tiny G and D."""
    config = {
        "generator": {"ngf": 8, "n_downsample": 2, "n_blocks": 2},
        "discriminator": {"ndf": 8},
        "data": {
            "train": [{"format": "7scenes", "root": str(SEVEN_SCENES), "frames": "0-3"}],
            "val": [{"format": "7scenes", "root": str(SEVEN_SCENES), "frames": "0-3"}],
            "val_scale": 0.2,
            "transform": {
                "size": [96, 128],
                "scale": [0.2, 0.2],
                "flip": False,
                "brightness": 0,
                "contrast": 0,
                "saturation": 0,
            },
        },
        "train": {
            "out_dir": str(out_dir),
            "steps": 10,
            "batch_size": 4,
            "num_workers": 0,
            "log_every": 5,
            "val_every": 1000,
            "checkpoint_every": 1000,
        },
    }
    for section, values in sections.items():
        config[section] = {**config.get(section, {}), **values}
    return config


def write_config(path: Path, config: dict) -> Path:
    path.write_text(yaml.safe_dump(config))
    return path


def run_cli(*args: str, cwd: Path = REPO, package: str = "cli") -> subprocess.CompletedProcess:
    """Run ``rgb2cloud`` (or, with ``package="lab"``, ``rgb2cloud-lab``) as a user would; fail with its output."""
    result = subprocess.run([sys.executable, "-m", package, *args], cwd=cwd, capture_output=True, text=True)
    assert result.returncode == 0, f"{package} {' '.join(args)} failed:\n{result.stdout}\n{result.stderr}"
    return result


def evaluate_cli(model: Path, out: Path, frames: str, *options: str, samples: int = 0) -> subprocess.CompletedProcess:
    """``rgb2cloud evaluate`` of a checkpoint or version folder on 7-Scenes test frames, plus ``options``."""
    return run_cli(
        "evaluate",
        str(model),
        "--format",
        "7scenes",
        "--root",
        str(SEVEN_SCENES),
        "--frames",
        frames,
        "--out",
        str(out),
        "--samples",
        str(samples),
        *options,
    )


def export_args(checkpoint: Path, metrics: Path, registry: Path) -> list[str]:
    """``rgb2cloud export`` arguments publishing ``tiny 0.1.0``, parity-checked on the real TUM frame."""
    return [
        "export",
        str(checkpoint),
        "--name",
        "tiny",
        "--version",
        "0.1.0",
        "--metrics",
        str(metrics),
        "--parity-image",
        str(TUM_FRAME / "TUM_color.png"),
        "--registry",
        str(registry),
    ]


def png_header(width: int, height: int) -> bytes:
    """A PNG of which only the header is written: Pillow reads its size, and refuses a bomb, on opening it,
    and never reaches pixel data (there is none)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IEND", b"")


def save_png16(path: Path, array: np.ndarray) -> None:
    Image.fromarray(array.astype(np.uint16)).save(path)


@pytest.fixture(scope="session")
def trained_checkpoint(tmp_path_factory) -> Path:
    """A tiny generator trained for a few steps on real frames (for export and evaluate tests).

    It works at half the input's resolution (``work_scale`` 2) and trains on views of mixed extent, as the
    bundled default does, so export parity and the service cover the pool-in, upsample-out graph.
    """
    out = tmp_path_factory.mktemp("tiny-run")
    config = tiny_config(out / "run", train={"steps": 6}, generator={"work_scale": 2})
    config["data"]["transform"].update(extent=[0.5, 1.0], whole_share=0.5)  # views of mixed extent, as 0.9.0's
    config = write_config(out / "config.yaml", config)
    run_cli("train", str(config))
    return out / "run" / "checkpoints" / "last.pt"


@pytest.fixture(scope="session")
def registry(trained_checkpoint, tmp_path_factory) -> Path:
    """A registry holding the tiny trained generator, published the way users publish."""
    out = tmp_path_factory.mktemp("registry")
    evaluate_cli(trained_checkpoint, out / "eval", "850-851")
    run_cli(*export_args(trained_checkpoint, out / "eval" / "metrics.json", out / "weights"))
    return out / "weights"
