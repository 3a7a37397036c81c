"""The Azure Kinect factory calibration, as the camera of each recording mode.

``calibration.json`` (attached to every ``k4arecorder`` file) holds each camera normalised to its full
sensor (1024x1024 depth, 4096x3072 colour): principal point and focal length as fractions of the
sensor, with 0 at a pixel's corner, and a Brown-Conrady lens (``ModelParameters``: cx, cy, fx, fy,
k1-k6, codx, cody, p2, p1). A recording mode bins and crops the sensor; the Sensor SDK derives each
mode's camera (``transformation_get_mode_specific_camera_calibration``) with the windows in
``DEPTH_MODES`` and ``COLOUR_RESOLUTIONS``, and this module does the same, in OpenCV's convention
(0 at a pixel's centre) and with OpenCV's coefficient order for the lens.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from contract.errors import UserError
from contract.geometry import Intrinsics
from recordings.lens import Lens

#: The SDK's validity radius for a lens whose calibration left ``MetricRadius`` at 0 (about 120 degrees).
DEFAULT_METRIC_RADIUS = 1.7


@dataclass(frozen=True)
class SensorMode:
    """One recording mode of a sensor as the SDK derives its camera: the sensor binned to ``binned``
    pixels, then the ``size`` window at ``offset`` cut from it."""

    binned: tuple[int, int]
    offset: tuple[int, int]
    size: tuple[int, int]


DEPTH_MODES = {
    "NFOV_2X2BINNED": SensorMode((512, 512), (96, 90), (320, 288)),
    "NFOV_UNBINNED": SensorMode((1024, 1024), (192, 180), (640, 576)),
    "WFOV_2X2BINNED": SensorMode((512, 512), (0, 0), (512, 512)),
    "WFOV_UNBINNED": SensorMode((1024, 1024), (0, 0), (1024, 1024)),
}
COLOUR_RESOLUTIONS = {
    "720P": SensorMode((1280, 960), (0, 120), (1280, 720)),
    "1080P": SensorMode((1920, 1440), (0, 180), (1920, 1080)),
    "1440P": SensorMode((2560, 1920), (0, 240), (2560, 1440)),
    "1536P": SensorMode((2048, 1536), (0, 0), (2048, 1536)),
    "2160P": SensorMode((3840, 2880), (0, 360), (3840, 2160)),
    "3072P": SensorMode((4096, 3072), (0, 0), (4096, 3072)),
}
#: Where the calibration file keeps each camera (``Location``), and what it is for (``Purpose``), as a fallback.
CAMERAS = {
    "depth": ("CALIBRATION_CameraLocationD0", "Depth"),
    "colour": ("CALIBRATION_CameraLocationPV0", "PhotoVideo"),
}


def attached_calibration(container: Any, path: Path) -> dict[str, Any]:
    """The factory calibration attached to the recording, as JSON."""
    attached = [a for a in container.streams.attachments if str(a.name).lower().endswith("calibration.json")]
    if not attached:
        raise UserError(f"{path}: no calibration.json attachment; fit needs the device calibration k4arecorder stores")
    try:
        return json.loads(bytes(attached[0].data))["CalibrationInformation"]
    except (ValueError, KeyError, TypeError) as e:
        raise UserError(f"{path}: its calibration.json is not an Azure Kinect calibration ({_wrong(e)})") from None


def _wrong(error: Exception) -> str:
    """What a calibration.json that raised ``error`` lacks, in words."""
    if isinstance(error, KeyError):
        return f"it has no {error.args[0]!r} entry"
    if isinstance(error, ValueError) and "JSON" in type(error).__name__ + str(error):
        return "not JSON"
    return "a value there is not a number, or a list of the wrong length"


def _camera(path: Path, calibration: dict[str, Any], which: str) -> dict[str, Any]:
    location, purpose = CAMERAS[which]
    cameras = calibration.get("Cameras", [])
    for key, value in (("Location", location), ("Purpose", f"CALIBRATION_CameraPurpose{purpose}")):
        found = [c for c in cameras if isinstance(c, dict) and c.get(key) == value]
        if found:
            return found[0]
    raise UserError(f"{path}: its calibration.json has no {which} camera ({location})")


def mode_lens(path: Path, calibration: dict[str, Any], which: str, mode: SensorMode) -> Lens:
    """One camera in the recording's mode: the SDK's binning and crop of the normalised calibration, with the
    pixel-centre convention (the calibration's 0 is a pixel's corner, OpenCV's its centre), and its lens."""
    camera = _camera(path, calibration, which)
    try:
        intrinsics = camera["Intrinsics"]
        params = [float(v) for v in intrinsics["ModelParameters"]]
        model = intrinsics["ModelType"]
        sensor = (int(camera["SensorWidth"]), int(camera["SensorHeight"]))
        radius = float(camera.get("MetricRadius", 0.0))
        cx, cy, fx, fy, k1, k2, k3, k4, k5, k6, _codx, _cody, p2, p1 = params[:14]
    except (KeyError, TypeError, ValueError) as e:
        raise UserError(f"{path}: its calibration.json's {which} camera is incomplete ({_wrong(e)})") from None
    if model != "CALIBRATION_LensDistortionModelBrownConrady":
        raise UserError(
            f"{path}: {which} lens model {model!r}: only CALIBRATION_LensDistortionModelBrownConrady is read"
        )
    if which == "colour" and sensor[0] * 9 == sensor[1] * 16:  # a 16:9 calibration: the SDK moves it onto 4:3 first
        cy, fy = (
            (cy * sensor[1] + (sensor[0] * 3 // 4 - sensor[1]) / 2) / (sensor[0] * 3 / 4),
            fy * sensor[1] / (sensor[0] * 3 / 4),
        )
    (bw, bh), (ox, oy), (w, h) = mode.binned, mode.offset, mode.size
    pinhole = Intrinsics(fx * bw, fy * bh, cx * bw - ox - 0.5, cy * bh - oy - 0.5, w, h)
    coefficients = (k1, k2, p1, p2, k3, k4, k5, k6)  # OpenCV's rational model, in its order
    return Lens(pinhole, "rational_polynomial", coefficients, radius if radius > 1e-4 else DEFAULT_METRIC_RADIUS)


def depth_to_colour(path: Path, calibration: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(rotation, translation in metres) taking a point from the depth camera's frame into the colour camera's.

    Each camera's ``Rt`` maps the device frame (the depth camera's) into that camera, so depth to
    colour is ``Rt_colour`` after the inverse of ``Rt_depth``, as the SDK composes them.
    """
    poses = []
    for which in ("depth", "colour"):
        try:
            rt = _camera(path, calibration, which)["Rt"]
            poses.append(
                (np.asarray(rt["Rotation"], float).reshape(3, 3), np.asarray(rt["Translation"], float).reshape(3))
            )
        except (KeyError, TypeError, ValueError) as e:
            raise UserError(f"{path}: its calibration.json's {which} pose is incomplete ({_wrong(e)})") from None
    (rd, td), (rc, tc) = poses
    rotation = rc @ rd.T
    return rotation, tc - rotation @ td
