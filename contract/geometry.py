"""Camera geometry shared by the trainer and the service. Torch-free on purpose.

Everything here works on NumPy arrays so that the serving install (ONNX Runtime,
no torch) and the trainer use the *same* back-projection and the same intrinsics
bookkeeping. Conventions follow the paper's formula (5) and Open3D's vocabulary:

    pz = d,  px = pz * (u - cx) / fx,  py = pz * (v - cy) / fy

with (u, v) the pixel column and row, x right, y down, z forward, in metres.
Pixel centres sit at integer coordinates, so a resize by ``s`` maps a
coordinate ``c`` to ``(c + 0.5) * s - 0.5``; that keeps the principal point on
the same physical ray, which plain ``c * s`` does not.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from pydantic.dataclasses import dataclass

from contract.errors import UserError


def resized_coordinate(coordinate: float, scale: float) -> float:
    """A pixel coordinate after its image is resized by ``scale``: the one pixel-centre rule."""
    return (coordinate + 0.5) * scale - 0.5


Positive = Annotated[float, Field(gt=0)]
Pixels = Annotated[int, Field(gt=0)]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels of an image of ``width`` x ``height``: the one camera type.

    The card stores its training camera as one, the service builds one per photo, and every
    trainer reader puts one in each frame; a pydantic dataclass, so a card or a config is
    validated on read and the hot paths keep positional construction.
    """

    fx: Positive
    fy: Positive
    cx: float
    cy: float
    width: Pixels
    height: Pixels

    def resized(self, width: int, height: int) -> Intrinsics:
        """The same camera after resizing its image to ``width`` x ``height``."""
        sx = width / self.width
        sy = height / self.height
        return Intrinsics(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=resized_coordinate(self.cx, sx),
            cy=resized_coordinate(self.cy, sy),
            width=width,
            height=height,
        )

    def cropped(self, left: int, top: int, width: int, height: int) -> Intrinsics:
        """The camera seen through a ``width`` x ``height`` window at (left, top)."""
        return Intrinsics(self.fx, self.fy, self.cx - left, self.cy - top, width, height)

    def flipped(self) -> Intrinsics:
        """The camera after mirroring its image left to right (cx mirrors)."""
        return Intrinsics(self.fx, self.fy, self.width - 1 - self.cx, self.cy, self.width, self.height)

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def ray_factors(intrinsics: Intrinsics, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Formula (5)'s per-column (u - cx) / fx and per-row (v - cy) / fy, every stride-th pixel.

    A point is (d * x_factor[u], d * y_factor[v], d): one multiply per axis, no
    full ray grid.
    """
    x = (np.arange(0, intrinsics.width, stride, dtype=np.float32) - intrinsics.cx) / intrinsics.fx
    y = (np.arange(0, intrinsics.height, stride, dtype=np.float32) - intrinsics.cy) / intrinsics.fy
    return x, y


#: One coloured point: metres, then 8-bit colour. It is also the binary PLY vertex layout,
#: so the service writes a cloud to PLY with one copy.
POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])


def point_cloud(
    depth: np.ndarray,
    rgb: np.ndarray,
    intrinsics: Intrinsics,
    *,
    stride: int = 1,
    min_depth: float = 0.0,
    max_depth: float = float("inf"),
) -> np.ndarray:
    """Formula (5) at the valid pixels: an (N,) array of ``POINT`` records, row-major.

    Pixels with no depth (0, NaN, inf) or outside [min_depth, max_depth] are dropped;
    ``stride`` keeps every stride-th row and column. The whole grid is filled
    field by field and the valid records are gathered once, already in the PLY
    vertex layout, so writing a PLY needs no per-field copy.
    """
    if stride < 1:
        raise ValueError("stride must be >= 1")
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(
            f"depth is {depth.shape[1]}x{depth.shape[0]} but the intrinsics are for "
            f"{intrinsics.width}x{intrinsics.height}"
        )
    d = depth[::stride, ::stride].astype(np.float32, copy=False)
    # Two comparisons do it all: NaN fails both, 0 fails the first, inf fails the second.
    lowest = max(min_depth, float(np.finfo(np.float32).tiny))
    highest = min(max_depth, float(np.finfo(np.float32).max))
    with np.errstate(invalid="ignore"):
        keep = (d >= lowest) & (d <= highest)
    x_factor, y_factor = ray_factors(intrinsics, stride)
    grid = np.empty(d.shape, dtype=POINT)
    np.multiply(d, x_factor[None, :], out=grid["x"])
    np.multiply(d, y_factor[:, None], out=grid["y"])
    grid["z"] = d
    pixels = rgb[::stride, ::stride]
    for i, channel in enumerate(("red", "green", "blue")):
        grid[channel] = pixels[..., i]
    # ``take`` with indices copies each 15-byte record whole; a boolean mask on a
    # structured array goes through numpy's generic per-item copy, which is much slower.
    return np.take(grid.reshape(-1), np.flatnonzero(keep))


def xyz(points: np.ndarray) -> np.ndarray:
    """(N, 3) float32 metres from ``POINT`` records."""
    return np.stack([points["x"], points["y"], points["z"]], axis=-1)


def colours(points: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours from ``POINT`` records."""
    return np.stack([points["red"], points["green"], points["blue"]], axis=-1)


#: The fewest grid cells per side an input is padded to: the generator's innermost feature map
#: is one cell per ``multiple`` pixels, and its reflection padding needs at least two.
MIN_GRID_CELLS = 2


def grid_padding(height: int, width: int, multiple: int) -> tuple[int, int]:
    """Rows and columns to add at the bottom and right to reach a multiple (and at least the smallest grid)."""
    smallest = MIN_GRID_CELLS * multiple
    return max(smallest - height, (-height) % multiple), max(smallest - width, (-width) % multiple)


def pad_to_multiple(image: np.ndarray, multiple: int) -> np.ndarray:
    """Pad an (H, W, ...) array at the bottom and right to a multiple of ``multiple``.

    Reflection keeps the border statistics the generator saw in training; an
    image smaller than the pad falls back to repeating its edge.
    """
    pad_h, pad_w = grid_padding(image.shape[0], image.shape[1], multiple)
    if pad_h == 0 and pad_w == 0:
        return image
    widths = [(0, pad_h), (0, pad_w)] + [(0, 0)] * (image.ndim - 2)
    mode = "reflect" if pad_h < image.shape[0] and pad_w < image.shape[1] else "edge"
    return np.pad(image, widths, mode=mode)


class ColourCamera(BaseModel):
    """The colour camera as seen from the depth camera, in pixels of the same image size.

    Raw Kinect-style recordings come from two cameras a few millimetres apart: the
    trainer registers depth into this camera, and a card's metrics say when they were
    read through it, so it is part of the shared vocabulary.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float = 0.0
    #: Turn about the optical axis relative to the depth camera, degrees (x towards y). The two
    #: lenses are mounted separately, so a fraction of a degree is usual; at 300 px from the
    #: centre, 0.5 degrees moves an edge by about 2.6 px.
    roll_deg: float = 0.0

    @classmethod
    def from_flow(cls, text: str) -> ColourCamera:
        """Parse the YAML flow ``flow`` writes (and configs and command lines use); ValueError if malformed."""
        import yaml

        try:
            return cls.model_validate(yaml.safe_load(text))
        except yaml.YAMLError as e:
            raise UserError(f"{text!r} is not YAML: {e}") from None

    def intrinsics(self, width: int, height: int) -> Intrinsics:
        return Intrinsics(self.fx, self.fy, self.cx, self.cy, width, height)

    def flow(self) -> str:
        """YAML flow, as a data source's ``colour_camera`` and ``evaluate --colour-camera`` take it.

        Offsets at their default (no baseline, no roll) are left out, so the common case
        reads as plain intrinsics.
        """
        fields = self.model_dump(exclude_defaults=True)
        return "{" + ", ".join(f"{k}: {round(v, 4):g}" for k, v in fields.items()) + "}"

    def resized(self, scale: float) -> ColourCamera:
        """The same camera pair after both images are resized by ``scale`` (pixel-centre convention)."""
        if scale == 1.0:
            return self
        return self.model_copy(
            update={
                "fx": self.fx * scale,
                "fy": self.fy * scale,
                "cx": resized_coordinate(self.cx, scale),
                "cy": resized_coordinate(self.cy, scale),
            }
        )
