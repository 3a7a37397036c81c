"""A camera as its images are stored: pinhole intrinsics plus the lens distortion to undo first.

ROS bags (a CameraInfo's ``D``) and Azure Kinect recordings (the factory calibration's Brown-Conrady
model) both describe real lenses. Registration (``recordings.registration.reproject_depth``) is pinhole
geometry, so every reader undoes the distortion here, with OpenCV, before depth is moved.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from contract.geometry import Intrinsics


@dataclass(frozen=True)
class Lens:
    """The pinhole intrinsics of the undistorted images, and the distortion that the stored ones carry.

    ``model`` is a ROS distortion model name (``plumb_bob`` and ``rational_polynomial`` are OpenCV's
    standard model with 5 or 8 coefficients, ``equidistant`` its fisheye); no distortion is ``None``.
    Undoing it keeps the camera matrix (OpenCV's ``initUndistortRectifyMap`` with the same K), so
    the intrinsics describe the undistorted images. ``max_radius`` bounds where the model is valid
    (the Azure Kinect calibration's ``MetricRadius``, in normalised image coordinates): pixels whose
    ray lies beyond it are left empty rather than filled from where the polynomial folds back.
    """

    camera: Intrinsics
    model: str | None = None
    coefficients: tuple[float, ...] = ()
    max_radius: float | None = None

    def undistorted(self, image: np.ndarray, nearest: bool) -> np.ndarray:
        """``image`` with the lens distortion removed: bilinear for photos, nearest for depth (no blended depth)."""
        if self.model is None:
            return image
        import cv2

        interpolation = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        return cv2.remap(image, *self._maps, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    @cached_property
    def _maps(self) -> tuple[np.ndarray, np.ndarray]:
        """Where each undistorted pixel is read from: built once per lens, not once per frame."""
        import cv2

        k = self.camera
        matrix = np.array([[k.fx, 0, k.cx], [0, k.fy, k.cy], [0, 0, 1]], np.float64)
        coefficients = np.asarray(self.coefficients, np.float64)
        size = (k.width, k.height)
        if self.model == "equidistant":
            maps = cv2.fisheye.initUndistortRectifyMap(matrix, coefficients[:4], np.eye(3), matrix, size, cv2.CV_32FC1)
        else:
            maps = cv2.initUndistortRectifyMap(matrix, coefficients, None, matrix, size, cv2.CV_32FC1)
        if self.max_radius is not None:
            v, u = np.mgrid[0 : k.height, 0 : k.width]
            beyond = np.hypot((u - k.cx) / k.fx, (v - k.cy) / k.fy) > self.max_radius
            maps = tuple(np.where(beyond, np.float32(-1), m) for m in maps)
        return maps
