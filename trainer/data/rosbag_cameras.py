"""A ROS CameraInfo as the camera its images were taken with: intrinsics at the images' size, and the lens.

A CameraInfo can disagree with its images: a driver reports the sensor's full size, a camera was never
calibrated (K all zeros), or the lens distortion is left for the user to undo. Each is either made right
(scaled to the images' size, undistorted with OpenCV before registration) or refused in one line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from contract.errors import UserError
from contract.geometry import Intrinsics
from trainer.data.folders import CameraFile
from trainer.data.lens import Lens

#: CameraInfo distortion models this reader undoes, with OpenCV: the standard polynomial ones and the fisheye.
DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "equidistant")


def camera_info_lens(
    path: Path, topic: str, info: Any, images: tuple[str, int, int], notes: list[str], override: CameraFile
) -> Lens:
    """The camera a CameraInfo describes, at its images' size, with ``override``'s intrinsics in place.

    A CameraInfo for another size of the same images (a driver that reports the sensor's full size) is
    scaled when the aspect ratio agrees, and refused when it does not; an uncalibrated one (K all zeros)
    is refused unless the command line gives the intrinsics.
    """
    k = np.asarray(info.k if hasattr(info, "k") else info.K, dtype=np.float64).reshape(3, 3)  # ROS 2 | ROS 1
    width, height = int(info.width), int(info.height)
    image_topic, image_width, image_height = images
    image = (image_width, image_height)
    if (width, height) == (0, 0) and 0 not in image:
        width, height = image
    camera = CameraFile(float(k[0, 0]) or None, float(k[1, 1]) or None, float(k[0, 2]), float(k[1, 2]))
    camera = camera.merged(override)
    if not (camera.fx and camera.fy and camera.fx > 0 and camera.fy > 0 and width > 0 and height > 0):
        raise UserError(
            f"{path}: {topic}: the camera matrix K is not a calibration (fx {k[0, 0]:g}, fy {k[1, 1]:g}, "
            f"{width}x{height}); record a calibrated camera_info, or pass --fx --fy --cx --cy for the colour camera"
        )
    intrinsics = Intrinsics(camera.fx, camera.fy, camera.cx, camera.cy, width, height)
    if 0 not in image and image != (width, height):
        if abs(image[0] / image[1] - width / height) > 0.01 * width / height:
            raise UserError(
                f"{path}: {topic} describes {width}x{height} images, but {image_topic}'s are "
                f"{image[0]}x{image[1]}, another shape: record the camera_info of the stream itself"
            )
        intrinsics = intrinsics.resized(*image)
        notes.append(f"{topic}: its {width}x{height} camera scaled to {image_topic}'s {image[0]}x{image[1]} images")
    coefficients = tuple(float(v) for v in (info.d if hasattr(info, "d") else info.D))
    if not any(coefficients):
        return Lens(intrinsics)
    model = info.distortion_model
    if model not in DISTORTION_MODELS:
        raise UserError(
            f"{path}: {topic}: lens distortion model {model!r} cannot be undone here (only "
            f"{', '.join(DISTORTION_MODELS)}); record the rectified image topic instead"
        )
    notes.append(f"{image_topic}: {model} lens distortion undone ({', '.join(f'{c:.4g}' for c in coefficients)})")
    return Lens(intrinsics, model, coefficients)


def same_camera(a: Intrinsics, b: Intrinsics) -> bool:
    """Whether two cameras are one: the same image size and intrinsics (to 1e-4)."""
    return (a.width, a.height) == (b.width, b.height) and np.allclose(
        [a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], rtol=1e-4
    )


@dataclass(frozen=True)
class Geometry:
    """How a depth frame becomes depth in the colour camera: both lenses, the rigid transform, the units."""

    depth: Lens
    colour: Lens
    rotation: np.ndarray
    translation: np.ndarray
    units_m: float

    @property
    def moves(self) -> bool:
        """Whether depth must be reprojected at all (not when it is already in the colour camera)."""
        identity = np.allclose(self.rotation, np.eye(3)) and np.allclose(self.translation, 0)
        return not (identity and same_camera(self.depth.camera, self.colour.camera))
