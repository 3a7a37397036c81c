"""Run an exported generator on one image: the contract every runner keeps, and ONNX Runtime's.

Every runner (``ExportedGenerator``) takes HxWx3 uint8 and gives back HxW float32
of the generator's tanh output, at the input's size. Padding to the generator's
grid and cropping back are ``to_grid`` and ``from_grid`` here, once, for every
runner: ONNX Runtime below, the service's optional TorchScript backend
(``app.torchscript``) and the trainer's eager one (``trainer.inference``).

Torch-free: the service's default install has no torch.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, Protocol

import numpy as np

from contract.codec import rgb_to_input
from contract.geometry import pad_to_multiple

#: The graphs a version can ship: fp32 always, int8 beside it when exported with ``--precision int8``.
Precision = Literal["fp32", "int8"]
#: How a generator runs: a graph at its own precision, or the fp32 graph on the CPU's bf16 units (OpenVINO).
RunPrecision = Literal["fp32", "bf16", "int8"]
#: When a reduced precision (int8, bf16) gives "the same depth" as fp32, pixel for pixel, on the version's sample
#: photo at its own size and at twice it: at export (int8), and again wherever a version loads, before that
#: precision is served there. Bounds chosen from what the real graphs measure, with a margin (docs/api.md,
#: "Engines"): the bundled 0.9.0's int8 graph has a median relative difference of 0.019, 98.9% of pixels within
#: 1.10x and a median ratio 1.004 at the worse of the two sizes (bench/same_depth.py); bf16 on AMX is far closer.
#: A uniform 1.05x bias (median relative difference 0.05, median ratio 1.05) fails two bounds.
SAME_DEPTH_MEDIAN_REL = 0.03
SAME_DEPTH_WITHIN = 1.10
SAME_DEPTH_SHARE = 0.95
SAME_DEPTH_BIAS = 1.02


def depth_agreement(reference: np.ndarray, depth: np.ndarray) -> dict[str, float]:
    """How far reduced-precision depth is from fp32 depth, over every pixel fp32 gives depth.

    ``lost``: the share of those pixels with no finite positive depth here (never allowed);
    ``median_rel``: the median of |depth / fp32 - 1|; ``within``: the share within ``SAME_DEPTH_WITHIN``x;
    ``median_ratio``: the median of depth / fp32, which a uniform bias moves and noise does not.
    """
    expected = np.isfinite(reference) & (reference > 0)
    given = np.isfinite(depth) & (depth > 0)
    if not expected.any():
        return {"lost": 0.0, "median_rel": 0.0, "within": 1.0, "median_ratio": 1.0}
    both = expected & given
    lost = float((expected & ~given).sum() / expected.sum())
    if not both.any():
        return {"lost": lost, "median_rel": 1.0, "within": 0.0, "median_ratio": 0.0}
    ratio = depth[both].astype(np.float64) / reference[both]
    within = float((np.abs(np.log(ratio)) < np.log(SAME_DEPTH_WITHIN)).sum() / expected.sum())
    return {
        "lost": lost,
        "median_rel": float(np.median(np.abs(ratio - 1))),
        "within": within,
        "median_ratio": float(np.median(ratio)),
    }


def disagreement(parity: dict[str, float]) -> str | None:
    """Why ``depth_agreement``'s figures are not "the same depth" (every bound that fails), or None when they are."""
    reasons = []
    if parity["lost"] > 0:
        reasons.append(f"{parity['lost'] * 100:.3g}% of the pixels fp32 gives depth have none")
    if parity["median_rel"] > SAME_DEPTH_MEDIAN_REL:
        reasons.append(f"median relative difference {parity['median_rel']:.2%} (at most {SAME_DEPTH_MEDIAN_REL:.0%})")
    if parity["within"] < SAME_DEPTH_SHARE:
        reasons.append(
            f"{parity['within']:.1%} of pixels within {SAME_DEPTH_WITHIN:.2f}x (at least {SAME_DEPTH_SHARE:.0%})"
        )
    if not 1 / SAME_DEPTH_BIAS <= parity["median_ratio"] <= SAME_DEPTH_BIAS:
        reasons.append(f"depth {parity['median_ratio']:.3f}x fp32's at the median (a bias; at most {SAME_DEPTH_BIAS}x)")
    return "; ".join(reasons) or None


def agreement_line(parity: dict[str, float]) -> str:
    """``depth_agreement``'s figures in one line, as ``rgb2cloud export`` prints them."""
    return (
        f"median relative difference {parity['median_rel']:.2%}, {parity['within']:.1%} of pixels within "
        f"{SAME_DEPTH_WITHIN:.2f}x, median ratio {parity['median_ratio']:.3f}, depth lost on {parity['lost']:.2%}"
    )


def check_sizes(photo: np.ndarray) -> list[np.ndarray]:
    """A check photo at its own size and at twice it (bilinear), where every engine and precision is compared
    with ONNX Runtime fp32: a graph may differ only where the service runs it larger than the photo."""
    from PIL import Image

    height, width = photo.shape[:2]
    larger = Image.fromarray(photo).resize((2 * width, 2 * height), Image.Resampling.BILINEAR)
    return [photo, np.asarray(larger)]


def worst_agreement(parities: list[dict[str, float]]) -> dict[str, float]:
    """The worst of each figure over several photos (the median ratio furthest from 1)."""
    return {
        "lost": max(p["lost"] for p in parities),
        "median_rel": max(p["median_rel"] for p in parities),
        "within": min(p["within"] for p in parities),
        "median_ratio": max((p["median_ratio"] for p in parities), key=lambda r: abs(np.log(max(r, 1e-9)))),
    }


class ExportedGenerator(Protocol):
    multiple: int

    def predict_raw(self, rgb: np.ndarray, *, once: bool = False) -> np.ndarray:
        """The generator's raw output on ``rgb``. ``once`` marks a one-off run larger than the runner usually
        sees (the load-time check at twice the sample): a runner that keeps memory for its largest input so
        far (ONNX Runtime's arena) gives back what that run grew, so checking costs no memory held for good."""
        ...


def to_grid(rgb: np.ndarray, multiple: int) -> np.ndarray:
    """HxWx3 uint8 -> the generator's (1, 3, H', W') input, padded to a multiple of ``multiple``."""
    return rgb_to_input(pad_to_multiple(rgb, multiple))


def from_grid(output: np.ndarray, height: int, width: int) -> np.ndarray:
    """The generator's (1, 1, H', W') output cropped back to the photo's HxW, float32."""
    return np.ascontiguousarray(output[0, 0, :height, :width], dtype=np.float32)


class OnnxGenerator:
    """ONNX Runtime on the CPU with a fixed thread count (the service sizes it to its cores)."""

    def __init__(self, path: Path, multiple: int, threads: int = 0):
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name
        self.multiple = multiple
        self._shrink = ort.RunOptions()
        self._shrink.add_run_config_entry("memory.enable_memory_arena_shrinkage", "cpu:0")

    def predict_raw(self, rgb: np.ndarray, *, once: bool = False) -> np.ndarray:
        """``once``: the arena is shrunk back after the run (ONNX Runtime's ``memory.enable_memory_arena_shrinkage``);
        on the bundled int8 graph, a check at 1280x960 would otherwise keep about 250 MB more for good."""
        options = self._shrink if once else None
        (y,) = self.session.run(None, {self.input_name: to_grid(rgb, self.multiple)}, options)
        return from_grid(y, *rgb.shape[:2])
