"""A ROS CameraInfo as the camera its images were taken with: intrinsics at the images' size, and the lens.

A CameraInfo can disagree with its images: a driver reports the sensor's full size, a camera was never
calibrated (K all zeros), or the lens distortion is left for the user to undo. Each is either made right
(scaled to the images' size, undistorted with OpenCV before registration) or refused in one line.

A rectified image (``image_rect``, as ROS's image_pipeline publishes it) is described by the same
CameraInfo as the raw image it was made from: its ``D`` and ``K`` are the raw image's, and the
rectified image's own camera is the left 3x3 of ``P``, with no distortion left to undo.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from contract.errors import UserError
from contract.geometry import Intrinsics
from recordings.folders import INTRINSIC_KEYS, CameraFile
from recordings.lens import Lens
from recordings.rosbag_images import Stream

#: CameraInfo distortion models this reader undoes, with OpenCV: the standard polynomial ones and the fisheye.
DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "equidistant")


def is_rectified(topic: str) -> bool:
    """Whether an image topic holds rectified images (``image_rect``, ``image_rect_raw``, ``image_rect_color``)."""
    return "image_rect" in topic.lower()


def _field(info: Any, name: str) -> np.ndarray:
    """A CameraInfo matrix by its ROS 2 (``k``) or ROS 1 (``K``) name."""
    return np.asarray(getattr(info, name.lower()) if hasattr(info, name.lower()) else getattr(info, name), np.float64)


def recorded_lens(
    path: Path, topic: str, info: Any, images: tuple[str, int, int], notes: list[str], rectified: bool
) -> Lens | None:
    """The camera a CameraInfo describes, at its images' size, with its lens; None when it is uncalibrated.

    ``images`` is the image topic, its images' width and height (0, 0 where unknown); ``rectified``: the
    camera of the rectified images (``P``, nothing to undo), else of the raw ones (``K`` and ``D``). A
    CameraInfo for another size of the same images (a driver that reports the sensor's full size) is
    scaled when the aspect ratio agrees, and refused when it does not.
    """
    image_topic, image_width, image_height = images
    image = (image_width, image_height)
    matrix = _field(info, "K").reshape(3, 3)
    if rectified:
        projection = _field(info, "P").reshape(3, 4)[:, :3]
        if projection[0, 0] > 0 and projection[1, 1] > 0:
            matrix = projection
        else:
            notes.append(f"{image_topic}: rectified, but {topic}'s P is not set: its K is taken as the camera")
    if not (matrix[0, 0] > 0 and matrix[1, 1] > 0):
        return None
    width, height = int(info.width), int(info.height)
    if (width, height) == (0, 0):
        width, height = image
    if width <= 0 or height <= 0:
        raise UserError(f"{path}: {topic} gives no image size and {image_topic}'s images cannot be measured")
    intrinsics = Intrinsics(matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], width, height)
    if 0 not in image and image != (width, height):
        if abs(image[0] / image[1] - width / height) > 0.01 * width / height:
            raise UserError(
                f"{path}: {topic} describes {width}x{height} images, but {image_topic}'s are "
                f"{image[0]}x{image[1]}, another shape: record the camera_info of the stream itself"
            )
        intrinsics = intrinsics.resized(*image)
        notes.append(f"{topic}: its {width}x{height} camera scaled to {image_topic}'s {image[0]}x{image[1]} images")
    coefficients = tuple(float(v) for v in _field(info, "D"))
    if rectified or not any(coefficients):
        return Lens(intrinsics)
    model = info.distortion_model
    if model not in DISTORTION_MODELS:
        raise UserError(
            f"{path}: {topic}: lens distortion model {model!r} cannot be undone here (only "
            f"{', '.join(DISTORTION_MODELS)}); record the rectified image topic instead"
        )
    notes.append(f"{image_topic}: {model} lens distortion undone ({', '.join(f'{c:.4g}' for c in coefficients)})")
    return Lens(intrinsics, model, coefficients)


def rectification(info: Any) -> np.ndarray:
    """A CameraInfo's ``R``: raw camera coordinates into the rectified images' (identity for a lone camera)."""
    rotation = _field(info, "R").reshape(3, 3)
    return rotation if np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) else np.eye(3)


def overridden_lens(
    path: Path, topic: str, recorded: Lens | None, images: tuple[str, int, int], override: CameraFile
) -> Lens:
    """``recorded`` with the command line's intrinsics in place, in the pixels of the images as recorded.

    The recorded camera is already at the images' size, so an override is never scaled; an uncalibrated
    camera (``recorded`` None) needs all four values.
    """
    own = CameraFile.of(recorded.camera) if recorded is not None else CameraFile()
    camera = own.merged(override)
    missing = [key for key in INTRINSIC_KEYS if getattr(camera, key) is None]
    if missing or not (camera.fx > 0 and camera.fy > 0):
        raise UserError(
            f"{path}: {topic}: the camera matrix K is all zeros, not a calibration; record a calibrated "
            f"camera_info, or pass all of --fx --fy --cx --cy for the colour camera"
            + (f" ({', '.join('--' + key for key in missing)} missing)" if override.sets_intrinsics else "")
        )
    width, height = (recorded.camera.width, recorded.camera.height) if recorded is not None else images[1:]
    if width <= 0 or height <= 0:
        raise UserError(f"{path}: {images[0]}'s images cannot be measured, so --fx --fy --cx --cy have no size")
    intrinsics = Intrinsics(camera.fx, camera.fy, camera.cx, camera.cy, width, height)
    return Lens(intrinsics) if recorded is None else replace(recorded, camera=intrinsics)


def same_camera(a: Intrinsics, b: Intrinsics) -> bool:
    """Whether two cameras are one: the same image size and intrinsics (to 1e-4)."""
    return (a.width, a.height) == (b.width, b.height) and np.allclose(
        [a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], rtol=1e-4
    )


def bag_geometry(
    path: Path,
    colour: tuple[Stream, str, Any],
    depth: tuple[Stream, str, Any],
    override: CameraFile,
    units: float,
    extrinsics: Callable[[], tuple[tuple[np.ndarray, np.ndarray], str]],
    notes: list[str],
) -> tuple[Geometry, str]:
    """Both lenses, the depth-to-colour transform and the depth units, and how the depth reaches the colour camera.

    ``colour`` and ``depth`` are each image stream, its CameraInfo's topic and message; ``extrinsics`` gives
    the bag's depth-to-colour transform and how it was found, asked for only where depth must move.

    The command line's intrinsics are the colour camera's, in its images' pixels. Depth already aligned
    to colour (by its topic, or a CameraInfo equal to the colour one) is in the raw colour image's
    pixels: with a raw colour topic it takes the colour lens, overrides and all, and is never moved;
    beside a rectified one it is undistorted with the raw lens and turned by ``R`` into the rectified
    camera. Other depth is moved with the bag's extrinsics (into the raw colour frame, then by ``R``).
    """
    (colour_stream, colour_topic, colour_info), (depth_stream, depth_topic, depth_info) = colour, depth
    rectified = is_rectified(colour_stream.topic)
    recorded = recorded_lens(path, colour_topic, colour_info, colour_stream.image, notes, rectified)
    colour_lens = overridden_lens(path, colour_topic, recorded, colour_stream.image, override)
    if override.sets_intrinsics:
        k = colour_lens.camera
        notes.append(f"colour camera with the command line's: fx {k.fx:g}, fy {k.fy:g}, cx {k.cx:g}, cy {k.cy:g}")
    raw_colour = (
        recorded_lens(path, colour_topic, colour_info, colour_stream.image, [], False) if rectified else recorded
    )
    if "aligned_depth_to_color" in depth_stream.topic:
        depth_lens = None
    else:
        depth_lens = recorded_lens(path, depth_topic, depth_info, depth_stream.image, notes, is_rectified(depth_topic))
        if depth_lens is None:
            raise UserError(
                f"{path}: {depth_topic}: the depth camera's matrix K is all zeros, not a calibration; record a "
                "calibrated camera_info for it, or depth aligned to colour"
            )
    if depth_lens is None or (raw_colour is not None and same_camera(raw_colour.camera, depth_lens.camera)):
        check_aligned_size(path, colour_stream, depth_stream)
        if not rectified:
            return Geometry(
                colour_lens, colour_lens, np.eye(3), np.zeros(3), units, aligned=True
            ), "depth is aligned to colour in the bag"
        if raw_colour is None:
            raise UserError(
                f"{path}: {colour_topic}: depth aligned to the raw colour image needs its calibrated K and D"
            )
        how = (
            f"depth is aligned to the raw colour image in the bag, and turned into {colour_stream.topic}'s camera by R"
        )
        return Geometry(raw_colour, colour_lens, rectification(colour_info), np.zeros(3), units, aligned=False), how
    (rotation, translation), how = extrinsics()
    if rectified:  # the extrinsics reach the raw colour frame; the rectified camera is turned from it by R
        turn = rectification(colour_info)
        rotation, translation = turn @ rotation, turn @ translation
    return Geometry(depth_lens, colour_lens, rotation, translation, units, aligned=False), how


def check_aligned_size(path: Path, colour: Stream, depth: Stream) -> None:
    """Depth aligned to colour is the colour images' size, pixel for pixel; a bag that says otherwise is refused."""
    sizes = {(colour.width, colour.height), (depth.width, depth.height)}
    if len(sizes) > 1 and (0, 0) not in sizes:
        raise UserError(
            f"{path}: {depth.topic} is said to be aligned to colour, but its images are {depth.width}x{depth.height} "
            f"and {colour.topic}'s {colour.width}x{colour.height}: pass --depth-topic for depth in its own camera"
        )


@dataclass(frozen=True)
class Geometry:
    """How a depth frame becomes depth in the colour camera: both lenses, the rigid transform, the units.

    ``aligned``: the bag's depth is already in the colour camera's pixels (``aligned_depth_to_color``,
    or both CameraInfos the same), so it shares the colour lens, command-line values and all, and is
    never moved, only brought to the written size.
    """

    depth: Lens
    colour: Lens
    rotation: np.ndarray
    translation: np.ndarray
    units_m: float
    aligned: bool
