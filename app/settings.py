"""Every setting of the service, in one place: environment variables prefixed RGB2CLOUD_."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from contract.encodings import STREAM_MAX_PIXELS
from contract.registries import checkout_weights, default_registry
from contract.resample import INFERENCE_MAX_PIXELS
from contract.runtime import RunPrecision

PREFIX = "RGB2CLOUD_"
#: Variables that were settings once, and what took their place. A deployment that still sets one would
#: otherwise start without a word and serve another model, so the service refuses to start.
RETIRED_VARIABLES = {
    "RGB2CLOUD_MODEL_NAME": "RGB2CLOUD_MODEL=NAME",
    "RGB2CLOUD_MODEL_VERSION": "RGB2CLOUD_MODEL=NAME:VERSION",
    "RGB2CLOUD_BACKEND": "RGB2CLOUD_ENGINE (onnxruntime, openvino, torchscript or auto)",
}


def unknown_variables(environ: Mapping[str, str]) -> list[str]:
    """One message per ``RGB2CLOUD_*`` variable in ``environ`` that is no setting: retired (with its successor)
    or unknown (a typo: it would be ignored, and the default used in its place)."""
    known = {PREFIX + name.upper() for name in Settings.model_fields}
    problems = []
    for variable in sorted(environ):
        if not variable.upper().startswith(PREFIX) or variable.upper() in known:
            continue
        if variable.upper() in RETIRED_VARIABLES:
            problems.append(f"{variable} is retired: set {RETIRED_VARIABLES[variable.upper()]} instead")
        else:
            problems.append(f"{variable} is not a setting (see app/settings.py for the RGB2CLOUD_* settings)")
    return problems


class Settings(BaseSettings):
    """Read from the environment (RGB2CLOUD_REGISTRY=..., RGB2CLOUD_PORT=...) or passed directly.

    The only reader of ``RGB2CLOUD_*`` variables: the service, ``fit``, ``export`` and the client all
    take their registries, host and port from here. The one exception is ``inference_max_pixels``, which
    the trainer (which never imports the service) reads through ``contract.resample.inference_max_pixels``
    under the same name and rules, so its tables are of the depth the service serves. A retired or
    unknown variable in the environment fails validation rather than being ignored.
    """

    model_config = SettingsConfigDict(env_prefix="RGB2CLOUD_", extra="forbid")

    registry: Path = Field(
        default_factory=default_registry,
        description="the user's registry, <name>/<version>/card.json, where fit publishes (default: "
        "$XDG_DATA_HOME/rgb2cloud/models); served beside the bundled one",
    )
    bundled_registry: Path = Field(
        default_factory=checkout_weights, description="the models shipped with rgb2cloud (the checkout's weights/)"
    )
    model: str | None = Field(
        None,
        description="the default model, NAME (its newest version) or NAME:VERSION, loaded at startup and served "
        "to requests without model=; unset: the bundled registry's model, else the only model there is",
    )
    max_loaded: int = Field(
        4, ge=2, description="models kept loaded at once: the default and at least one a request names"
    )
    engine: Literal["auto", "onnxruntime", "openvino", "torchscript"] = Field(
        "auto",
        description="what runs the generator: auto measures ONNX Runtime and OpenVINO on each version as it loads "
        "and keeps the fastest that passes its check, per precision; torchscript needs the train extra",
    )
    precision: RunPrecision | Literal["auto"] = Field(
        "auto",
        description="what requests without precision= get: auto, the faster of fp32 and bf16 (where this CPU has "
        "bf16 units and bf16 passes its check); fp32; bf16; or int8 where a version ships one. A precision a "
        "version cannot serve here falls back to fp32 and says why in X-Precision-Fallback",
    )
    threads: int = Field(
        default_factory=lambda: os.cpu_count() or 1, ge=1, description="threads each generator call uses"
    )
    workers: int = Field(
        2,
        ge=1,
        description="requests processed at once; generator calls still run one at a time on all threads, "
        "so the others decode and encode meanwhile",
    )
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=1, le=65535)

    max_upload_bytes: int = Field(20 * 1024 * 1024, ge=1, description="larger bodies get 413 before buffering")
    max_pixels: int = Field(40_000_000, ge=1, description="decoded width x height limit (pixel bombs)")
    inference_max_pixels: int = Field(
        INFERENCE_MAX_PIXELS,
        ge=1,
        description="the most pixels the generator sees: a photo resampled to the model's focal length beyond "
        "this is shrunk further; depth comes back at the photo's size",
    )
    max_queue: int = Field(8, ge=0, description="requests waiting for inference beyond this get 503")
    retry_after_s: int = Field(1, ge=0, description="Retry-After on 503")
    cors_origins: list[str] = Field(
        default_factory=list,
        description="allowed browser origins, for HTTP (CORS) and for opening a stream (its Origin header); "
        "none by default: only the service's own page",
    )
    max_streams: int = Field(4, ge=0, description="streams open at once; one more is closed with 1013")
    stream_max_frame_bytes: int = Field(
        8 * 1024 * 1024, ge=1, description="a larger stream frame gets an error of its own; the stream goes on"
    )
    stream_max_pixels: int = Field(
        STREAM_MAX_PIXELS, ge=1, description="a stream frame's decoded width x height limit (4K UHD by default)"
    )
    stream_idle_s: float = Field(30, gt=0, description="a stream that sends nothing for this long is closed (1001)")
    stream_send_timeout_s: float = Field(
        10,
        gt=0,
        description="a stream whose client takes no answer for this long (it stopped reading) is closed (1008): "
        "the service never holds more than one unsent answer for it",
    )

    @model_validator(mode="after")
    def _coherent(self) -> Settings:
        if problems := unknown_variables(os.environ):
            raise ValueError("; ".join(problems))
        if self.engine == "torchscript" and self.precision in ("int8", "bf16"):
            raise ValueError(
                f"RGB2CLOUD_PRECISION={self.precision} needs another RGB2CLOUD_ENGINE than torchscript, which runs "
                "the fp32 graph only"
            )
        return self
