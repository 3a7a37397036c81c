"""The one rescale rule: a photo is shown to a generator at the generator's own focal length.

A generator learned one camera (the card's ``camera``): things look as big as they looked
through it, and a photo from a longer lens makes everything look bigger, and so closer. As
Metric3D does with its canonical camera, every place that runs a model resamples the photo so
that its focal length equals the model's, runs the generator, and maps the depth back to the
photo's own pixels. Resampling changes no distance, so the depth in metres needs no correction.

The service, fit's held-out table, ``rgb2cloud evaluate``, training's validation and the int8
calibration all call this module and nothing else, so their numbers agree to the third decimal. One
decode differs: a JPEG the generator sees at exactly half its size the service decodes at half
(``app.imaging.Upload.rgb``) in place of this module's 2x2 mean of its full decode, which moved
held-out δ1 by 0.0001 at most (``bench/jpeg_half.py``).
Torch-free: the serving install has no torch.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable

import numpy as np
from PIL import Image

from contract.errors import UserError
from contract.geometry import Intrinsics

#: The most pixels the generator sees unless told otherwise (the service's ``inference_max_pixels``):
#: a photo that needs more at the model's focal length is shrunk further, bounding the cost of a wide view.
INFERENCE_MAX_PIXELS = 1280 * 960

#: The service's setting (``app.settings.Settings.inference_max_pixels``) as an environment variable.
INFERENCE_MAX_PIXELS_VARIABLE = "RGB2CLOUD_INFERENCE_MAX_PIXELS"


def inference_max_pixels() -> int:
    """The service's ``RGB2CLOUD_INFERENCE_MAX_PIXELS``, or its default where unset, read as the service reads it.

    ``evaluate``, ``fit``'s held-out scores and int8 calibration resample photos by it too, so a deployment
    that changes it gets tables of the depth it serves. The trainer never imports the service, so it reads
    the variable here, under the service's rule (a whole number, 1 or more).
    """
    text = os.environ.get(INFERENCE_MAX_PIXELS_VARIABLE)
    if text is None:
        return INFERENCE_MAX_PIXELS
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise UserError(f"{INFERENCE_MAX_PIXELS_VARIABLE}={text!r}: expected a whole number of pixels, 1 or more")
    return value


#: A generator run: HxWx3 uint8 at the model's camera in, HxW metres at the same size out.
DepthRun = Callable[[np.ndarray], np.ndarray]


def focal_ratio(width: float, height: float, max_pixels: int) -> float:
    """The generator's focal length over the model's for a photo that needs ``width`` x ``height`` to match.

    1 when the photo fits ``max_pixels`` at the model's focal length; below 1 when it must be
    shrunk further, and the generator then sees everything smaller, so farther, than in training.
    """
    return min(1.0, math.sqrt(max_pixels / (width * height)))


def generator_size(photo: Intrinsics, model: Intrinsics, max_pixels: int) -> tuple[tuple[int, int], float]:
    """(width, height) at which the photo has the model's focal length, and the focal ratio.

    Shrunk to ``max_pixels`` if over, which the ratio (below 1) then says.
    """
    width = photo.width * model.fx / photo.fx
    height = photo.height * model.fy / photo.fy
    ratio = focal_ratio(width, height, max_pixels)
    return (max(1, round(width * ratio)), max(1, round(height * ratio))), ratio


def to_model_camera(
    rgb: np.ndarray, photo: Intrinsics, model: Intrinsics, max_pixels: int = INFERENCE_MAX_PIXELS
) -> tuple[np.ndarray, float]:
    """The photo (HxWx3 uint8, taken with ``photo``) resampled to the model's focal length, and the focal ratio."""
    if (photo.width, photo.height) != (rgb.shape[1], rgb.shape[0]):
        raise ValueError(
            f"the photo is {rgb.shape[1]}x{rgb.shape[0]} but its camera is for {photo.width}x{photo.height}"
        )
    size, ratio = generator_size(photo, model, max_pixels)
    height, width = rgb.shape[:2]
    if size == (width, height):
        return rgb, ratio
    if (width, height) == (2 * size[0], 2 * size[1]):
        # Exactly twice the size: each pixel the generator sees is the mean of a 2x2 block, as a sensor with a
        # quarter of the pixels would gather its light; the pixel centres fall where bilinear's do, and it costs a
        # third as much. Held-out δ1 moved by 0.0001 at most where both were scored (docs/benchmarks.md). Larger
        # whole factors stay bilinear, unscored; training stays bilinear too, as its views are at any scale.
        return np.asarray(Image.fromarray(rgb).reduce(2)), ratio
    return np.asarray(Image.fromarray(rgb).resize(size, Image.Resampling.BILINEAR)), ratio


def depth_at_photo(
    run: DepthRun, rgb: np.ndarray, photo: Intrinsics, model: Intrinsics, max_pixels: int = INFERENCE_MAX_PIXELS
) -> tuple[np.ndarray, float]:
    """Depth in metres at the photo's own size, the generator having seen it at the model's focal length.

    Also returns the focal ratio: 1 unless ``max_pixels`` shrank the photo further.
    """
    seen, ratio = to_model_camera(rgb, photo, model, max_pixels)
    return depth_to_photo(run(seen), photo), ratio


def depth_to_photo(depth: np.ndarray, photo: Intrinsics) -> np.ndarray:
    """The generator's depth (metres, at the size ``to_model_camera`` gave) back at the photo's own pixels:
    the same array where the photo was shown as it is."""
    depth = np.asarray(depth, dtype=np.float32)
    height, width = depth.shape
    if (width, height) == (photo.width, photo.height):
        return depth
    if (photo.width, photo.height) == (2 * width, 2 * height):
        return bilinear_twice(depth)
    back = Image.fromarray(depth, mode="F").resize((photo.width, photo.height), Image.Resampling.BILINEAR)
    return np.asarray(back, dtype=np.float32)


def bilinear_twice(depth: np.ndarray) -> np.ndarray:
    """Pillow's bilinear resize of float32 ``depth`` to exactly twice its width and height, in NumPy.

    At twice the size every output pixel's centre falls a quarter of a pixel from its source pixel's, so
    bilinear weighs that pixel 3/4 and its neighbour on that side 1/4, the edge pixel standing in for the
    neighbour it lacks, as Pillow's does: the same depth to float32's rounding, in less than half of
    Pillow's time for a 320x240 depth (the stream's ``resample_back`` stage, docs/benchmarks.md).
    """
    padded = np.pad(depth, 1, mode="edge")
    height, width = depth.shape
    rows = np.empty((height + 2, 2 * width), dtype=np.float32)
    centre = 0.75 * padded[:, 1:-1]
    np.add(centre, 0.25 * padded[:, :-2], out=rows[:, 0::2])
    np.add(centre, 0.25 * padded[:, 2:], out=rows[:, 1::2])
    out = np.empty((2 * height, 2 * width), dtype=np.float32)
    centre = 0.75 * rows[1:-1]
    np.add(centre, 0.25 * rows[:-2], out=out[0::2])
    np.add(centre, 0.25 * rows[2:], out=out[1::2])
    return out
