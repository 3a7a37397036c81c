"""Which camera took the photo: the service resamples it to the model's camera (``contract.resample``).

The generator learned one camera (the card's ``camera``): things look as big as they
looked through it. A photo from a longer lens makes everything look bigger, and so
closer. As Metric3D does with its canonical camera, the service resamples each photo
so that its focal length equals the model's, runs the generator, and maps the depth
back to the photo's own pixels. Resampling changes no distance, so the depth in
metres needs no correction.

The focal length comes from, in order:

- ``query``: ``fx``/``fy`` in the request (one of them is enough: square pixels);
- ``exif``: the photo's EXIF, ``FocalLength`` with the focal-plane resolution, else
  ``FocalLengthIn35mmFilm`` (taken across the image diagonal, 43.27 mm on film);
- ``model``: the model's own camera, with its field of view across the photo's longer side.

The principal point is ``cx``/``cy`` when given, else the model camera's, scaled to the photo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from PIL import ExifTags, Image

from contract.geometry import Intrinsics

Source = Literal["query", "exif", "model"]
#: The 35 mm film frame's diagonal: what "35 mm equivalent" focal lengths are relative to.
FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)
#: EXIF focal lengths outside this many times the photo's longer side (a field of view under 3
#: degrees or over 157) are taken as wrong tags and ignored.
PLAUSIBLE_FOCAL = (0.1, 20.0)
#: FocalPlaneResolutionUnit -> millimetres (2 inch, 3 cm, 4 mm, 5 micrometre).
UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}
#: EXIF orientations that turn the image a quarter: the focal plane's x becomes the photo's y.
QUARTER_TURNS = {5, 6, 7, 8}


@dataclass(frozen=True)
class CameraQuery:
    """What the request says about the camera; any of it may be missing."""

    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None


@dataclass(frozen=True)
class PhotoCamera:
    """The photo's intrinsics at its own (upright) size, and where the focal length came from."""

    intrinsics: Intrinsics
    source: Source

    def header(self) -> str:
        k = self.intrinsics
        return f"{k.fx:.4f},{k.fy:.4f},{k.cx:.4f},{k.cy:.4f}"


def _number(value: object) -> float | None:
    try:
        number = float(value)  # EXIF rationals (IFDRational) convert; a zero denominator gives nan
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return number if math.isfinite(number) and number > 0 else None


def exif_focal(image: Image.Image) -> tuple[float, float] | None:
    """(fx, fy) in pixels of the upright photo from its EXIF, or None when the tags are missing or implausible."""
    try:
        exif = image.getexif()
        tags = exif.get_ifd(ExifTags.IFD.Exif)
    except Exception:  # malformed EXIF is no reason to refuse the photo
        return None
    width, height = image.size  # as stored, before the orientation is applied
    turned = exif.get(ExifTags.Base.Orientation) in QUARTER_TURNS
    focal_mm = _number(tags.get(ExifTags.Base.FocalLength))
    x_res = _number(tags.get(ExifTags.Base.FocalPlaneXResolution))
    y_res = _number(tags.get(ExifTags.Base.FocalPlaneYResolution))
    unit = UNIT_MM.get(tags.get(ExifTags.Base.FocalPlaneResolutionUnit, 2))
    focal: tuple[float, float] | None = None
    if focal_mm and x_res and y_res and unit:
        # The resolution is of the sensor's full image; a resized photo scales with its stored size.
        full_width = _number(tags.get(ExifTags.Base.ExifImageWidth)) or width
        full_height = _number(tags.get(ExifTags.Base.ExifImageHeight)) or height
        focal = (focal_mm * x_res / unit * width / full_width, focal_mm * y_res / unit * height / full_height)
    elif (f35 := _number(tags.get(ExifTags.Base.FocalLengthIn35mmFilm))) is not None:
        f = f35 * math.hypot(width, height) / FILM_DIAGONAL_MM
        focal = (f, f)
    if focal is None:
        return None
    longer = max(width, height)
    if not all(PLAUSIBLE_FOCAL[0] * longer <= f <= PLAUSIBLE_FOCAL[1] * longer for f in focal):
        return None
    return (focal[1], focal[0]) if turned else focal


def photo_camera(
    model: Intrinsics, width: int, height: int, query: CameraQuery, exif: tuple[float, float] | None
) -> PhotoCamera:
    """The photo's camera: the focal length from the query, its EXIF or the model, in that order."""
    source: Source
    if query.fx is not None or query.fy is not None:
        fx = query.fx if query.fx is not None else query.fy
        fy = query.fy if query.fy is not None else query.fx
        source = "query"
    elif exif is not None:
        (fx, fy), source = exif, "exif"
    else:
        scale = max(width, height) / max(model.width, model.height)
        fx, fy, source = model.fx * scale, model.fy * scale, "model"
    centred = model.resized(width, height)
    cx = query.cx if query.cx is not None else centred.cx
    cy = query.cy if query.cy is not None else centred.cy
    return PhotoCamera(Intrinsics(fx, fy, cx, cy, width, height), source)
