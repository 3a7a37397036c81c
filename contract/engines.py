"""The inference engines a version's ONNX graphs run on, and what this CPU offers them.

ONNX Runtime's CPU provider is the reference: every score and every card was made with it. OpenVINO
runs the same ONNX files, and on CPUs with bf16 matrix units (Intel AMX, AVX512-BF16) it can run the
fp32 graph in bf16 (``INFERENCE_PRECISION_HINT``), several times faster on AMX. Which engine and which
precision a loaded version serves is decided where it loads (``app.loading``), by a check of the depth
against ONNX Runtime fp32 and, for ``auto``, a measurement.

Torch-free: both engines are in the serving install.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Literal

import numpy as np

from contract.runtime import ExportedGenerator, OnnxGenerator, RunPrecision, from_grid, to_grid

#: The engines an ONNX graph runs on; ``torchscript`` runs a version's TorchScript file (the ``train`` extra).
Engine = Literal["onnxruntime", "openvino", "torchscript"]


class OpenVinoGenerator:
    """OpenVINO's CPU plugin with a fixed thread count, in fp32 or (``bf16``) on the CPU's bf16 units.

    The precision hint is always given: on a CPU with AMX, OpenVINO's default would be bf16, and an
    "fp32" path must be fp32.
    """

    def __init__(self, path: Path, multiple: int, threads: int = 0, bf16: bool = False):
        import openvino as ov

        core = ov.Core()
        config = {"INFERENCE_PRECISION_HINT": "bf16" if bf16 else "f32", "PERFORMANCE_HINT": "LATENCY"}
        if threads:
            config["INFERENCE_NUM_THREADS"] = threads
        self.compiled = core.compile_model(core.read_model(str(path)), "CPU", config)
        self.request = self.compiled.create_infer_request()
        self.multiple = multiple

    def predict_raw(self, rgb: np.ndarray, *, once: bool = False) -> np.ndarray:
        """The output copied out of the infer request's own buffer, which its next call overwrites. ``once``
        changes nothing here: a fresh infer request for a one-off run gave no memory back when measured."""
        self.request.infer({0: to_grid(rgb, self.multiple)})
        return from_grid(self.request.get_output_tensor(0).data, *rgb.shape[:2]).copy()


@lru_cache(maxsize=1)
def openvino_capabilities() -> tuple[str, ...]:
    """What OpenVINO's CPU plugin says this CPU offers (``FP32``, ``INT8``, ``BF16``, ...)."""
    import openvino as ov

    return tuple(ov.Core().get_property("CPU", "OPTIMIZATION_CAPABILITIES"))


def bf16_units() -> bool:
    """Whether this CPU has bf16 matrix units (AMX, AVX512-BF16), as OpenVINO sees them: without, bf16 would
    be emulated, slower than fp32, and is never offered."""
    return "BF16" in openvino_capabilities()


def runs(engine: Engine, precision: RunPrecision) -> str | None:
    """Why ``engine`` cannot run ``precision`` here, or None when it can."""
    if precision != "fp32" and engine == "torchscript":
        return "the torchscript engine runs the fp32 graph only"
    if precision == "bf16" and engine != "openvino":
        return f"the {engine} engine runs no bf16 (OpenVINO does, on CPUs with bf16 units)"
    if precision == "bf16" and not bf16_units():
        return f"this CPU has no bf16 units (OpenVINO offers {', '.join(openvino_capabilities())})"
    return None


def onnx_runner(engine: Engine, path: Path, multiple: int, threads: int, precision: RunPrecision) -> ExportedGenerator:
    """An ONNX graph's runner on ``engine`` (onnxruntime or openvino), bf16 where asked."""
    if engine == "openvino":
        return OpenVinoGenerator(path, multiple, threads, bf16=precision == "bf16")
    return OnnxGenerator(path, multiple, threads)
