"""How images and depth map to and from the generator's value ranges. Torch-free.

The generator ends in tanh, so its output lives in [-1, 1]. ``DepthEncoding``
is the documented, versioned mapping between that range and metres; it is
stored in every checkpoint and model card, and the service decodes with this
same code. Two kinds:

* ``log`` (default): y = 2 * (ln d - ln d_min) / (ln d_max - ln d_min) - 1.
  Equal output steps are equal *relative* depth steps, which is what REL,
  log10 and the delta accuracies measure, and it spends no range on the far
  field where Kinect noise grows with d^2.
* ``linear``: y = 2 * (d - d_min) / (d_max - d_min) - 1.

Depth outside [d_min, d_max] is clipped on encode. Missing depth (0) has no
encoding: callers carry a validity mask instead.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator


class DepthEncoding(BaseModel):
    """Maps metres to the generator's tanh range and back."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["log", "linear"] = "log"
    min_m: float = Field(0.25, gt=0)
    max_m: float = Field(10.0, gt=0)

    @model_validator(mode="after")
    def _ordered(self) -> DepthEncoding:
        if self.max_m <= self.min_m:
            raise ValueError(f"max_m ({self.max_m}) must exceed min_m ({self.min_m})")
        return self

    def encode(self, metres: np.ndarray) -> np.ndarray:
        """Metres -> [-1, 1] (float32). Callers mask missing pixels themselves."""
        d = np.clip(np.asarray(metres, dtype=np.float32), self.min_m, self.max_m)
        if self.kind == "log":
            lo, hi = math.log(self.min_m), math.log(self.max_m)
            y = 2.0 * (np.log(d) - lo) / (hi - lo) - 1.0
        else:
            y = 2.0 * (d - self.min_m) / (self.max_m - self.min_m) - 1.0
        return y.astype(np.float32)

    def decode(self, y: np.ndarray) -> np.ndarray:
        """[-1, 1] -> metres (float32), always within [min_m, max_m]."""
        t = (np.clip(np.asarray(y, dtype=np.float32), -1.0, 1.0) + 1.0) / 2.0
        if self.kind == "log":
            lo, hi = math.log(self.min_m), math.log(self.max_m)
            d = np.exp(lo + t * (hi - lo))
        else:
            d = self.min_m + t * (self.max_m - self.min_m)
        return d.astype(np.float32)


#: What the generator expects: NCHW float32 RGB scaled from [0, 255] to [-1, 1].
INPUT_ENCODING = "rgb, NCHW float32, value = uint8 / 127.5 - 1"


def rgb_to_input(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 -> (1, 3, H, W) float32 in [-1, 1], per ``INPUT_ENCODING``."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an HxWx3 uint8 image, got {rgb.shape} {rgb.dtype}")
    x = rgb.astype(np.float32).transpose(2, 0, 1)[None] / 127.5 - 1.0
    return np.ascontiguousarray(x, dtype=np.float32)
