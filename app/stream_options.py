"""A stream's options and what they resolve to: the query string a stream opens with, changed by each JSON
text message it sends, checked with the POST routes' names and ranges, and the model and request settings
each of its frames runs with. Apart from ``app.stream`` so the protocol's loops read on their own."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from starlette.concurrency import run_in_threadpool

from app.camera import CameraQuery
from app.catalog import ModelCatalog, RefusedModel, UnknownModel
from app.deps import CENTRE_RANGE, FOCAL_RANGE, MODEL_REFERENCE
from app.loading import LoadedModel
from app.pipeline import CloudOptions, FrameOptions, RequestSettings
from app.settings import Settings
from contract.runtime import RunPrecision

Focal = Annotated[float | None, Field(**FOCAL_RANGE, allow_inf_nan=False)]
Centre = Annotated[float | None, Field(**CENTRE_RANGE, allow_inf_nan=False)]


class StreamOptions(BaseModel):
    """A stream's options: the query string it opened with, changed by each JSON text message it sends.

    The same names and ranges as the POST routes' query parameters, plus the outputs and encodings.
    """

    model_config = ConfigDict(extra="forbid", protected_namespaces=())

    model: str | None = Field(None, max_length=200, pattern=MODEL_REFERENCE)
    fx: Focal = None
    fy: Focal = None
    cx: Centre = None
    cy: Centre = None
    precision: RunPrecision | Literal["auto"] | None = None
    output: Literal["depth", "pointcloud", "both"] = "depth"
    #: png16: a 16-bit PNG in millimetres; raw16: width x height little-endian uint16 millimetres, cheaper;
    #: raw32: width x height little-endian float32 metres, as computed (no millimetre rounding, no 65.535 m cap).
    depth_encoding: Literal["png16", "raw16", "raw32"] = "png16"
    #: ply: binary PLY; raw: float32 x, y, z of every point, then uint8 r, g, b of every point.
    cloud_encoding: Literal["ply", "raw"] = "ply"
    stride: int = Field(1, ge=1, le=64)
    min_depth: float = Field(0.0, ge=0, allow_inf_nan=False)
    max_depth: float = Field(100.0, gt=0, allow_inf_nan=False)
    #: temporal: each pixel blended with the last frame's where they agree (``app.temporal``); off by default.
    smooth: Literal["off", "temporal"] = "off"

    @model_validator(mode="after")
    def _ordered(self) -> StreamOptions:
        if self.min_depth > self.max_depth:
            raise ValueError(f"min_depth ({self.min_depth}) is greater than max_depth ({self.max_depth})")
        return self

    def frame(self) -> FrameOptions:
        cloud = CloudOptions(self.stride, self.min_depth, self.max_depth)
        return FrameOptions(self.output, self.depth_encoding, self.cloud_encoding, cloud)

    def camera(self) -> CameraQuery:
        return CameraQuery(self.fx, self.fy, self.cx, self.cy)


class OptionsError(Exception):
    """Options a stream cannot run with, and the status the POST routes would answer them with."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


def problems(error: ValidationError) -> str:
    """pydantic's errors as one line: ``fx: Input should be greater than or equal to 0.01; ...``."""
    parts = []
    for item in error.errors():
        where = ".".join(map(str, item["loc"]))
        parts.append(f"{where}: {item['msg']}" if where else item["msg"].removeprefix("Value error, "))
    return "; ".join(parts)


def parse_options(values: dict[str, Any]) -> StreamOptions:
    try:
        return StreamOptions.model_validate(values)
    except ValidationError as e:
        raise OptionsError(422, problems(e)) from None


async def resolve(
    catalog: ModelCatalog, options: StreamOptions, settings: Settings
) -> tuple[LoadedModel, RequestSettings]:
    """The model the options name (loaded off the event loop) and the request settings each frame runs with."""
    try:
        model = await run_in_threadpool(catalog.get, options.model) if options.model else catalog.default
    except (UnknownModel, RefusedModel) as e:
        raise OptionsError(404 if isinstance(e, UnknownModel) else 409, e.message) from None
    if model is None:
        raise OptionsError(503, "the model is not loaded yet")
    if options.precision is not None and options.precision in model.disagrees:
        raise OptionsError(409, f"precision={options.precision}: {model.label}: {model.unserved[options.precision]}")
    wanted = options.precision or settings.precision
    return model, RequestSettings(settings.stream_max_pixels, settings.inference_max_pixels, wanted, "the frame")
