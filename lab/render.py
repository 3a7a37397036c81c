"""A picture of a point cloud from a virtual camera beside the real one. NumPy only.

The report shows a predicted cloud next to the ground-truth cloud from the same
side view: seen from the capturing camera, any depth map looks right, so the
virtual camera orbits the cloud's centre to show the shape. Splatted points with
a z-buffer are enough for that, and need no OpenGL on a headless machine.
"""

from __future__ import annotations

import numpy as np
from PIL import Image

from contract.geometry import ColourCamera, colours, point_cloud, xyz
from recordings.frames import Frame


def _rotation(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """Yaw about the y axis (down), then pitch about the x axis (right)."""
    a, b = np.radians(yaw_deg), np.radians(pitch_deg)
    yaw = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    pitch = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return pitch @ yaw


def render_points(
    points: np.ndarray,
    colours: np.ndarray,
    centre: np.ndarray,
    *,
    yaw_deg: float = 35.0,
    pitch_deg: float = -15.0,
    size: tuple[int, int] = (360, 480),
    splat: int = 2,
) -> np.ndarray:
    """Render (N, 3) metres with (N, 3) uint8 colours; returns an HxWx3 uint8 image.

    The virtual camera is the capturing camera turned by ``yaw_deg`` and
    ``pitch_deg`` about ``centre`` (pass the same centre for clouds that are to
    be compared). The nearest point wins each pixel; the background is white.
    """
    height, width = size
    image = np.full((height, width, 3), 255, dtype=np.uint8)
    p = (points.astype(np.float64) - centre) @ _rotation(yaw_deg, pitch_deg).T + centre
    in_front = p[:, 2] > 0.1
    p, c = p[in_front], colours[in_front]
    focal = 0.8 * width
    u = np.floor(focal * p[:, 0] / p[:, 2] + width / 2).astype(np.int64)
    v = np.floor(focal * p[:, 1] / p[:, 2] + height / 2).astype(np.int64)
    du, dv = np.meshgrid(np.arange(splat), np.arange(splat))
    u = (u[:, None] + du.ravel()).ravel()
    v = (v[:, None] + dv.ravel()).ravel()
    z = np.repeat(p[:, 2], splat * splat)
    c = np.repeat(c, splat * splat, axis=0)
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    pixel, z, c = (v * width + u)[inside], z[inside], c[inside]
    order = np.lexsort((z, pixel))  # by pixel, nearest first
    first = np.unique(pixel[order], return_index=True)[1]
    winners = order[first]
    image.reshape(-1, 3)[pixel[winners]] = c[winners]
    return image


def render_pair(pred: np.ndarray, frame: Frame, colour: ColourCamera | None = None) -> Image.Image:
    """Predicted cloud | ground-truth cloud, one virtual side view about the truth's centre.

    A prediction in the colour camera's view (``colour``) is back-projected with that camera.
    """
    truth = point_cloud(frame.depth, frame.rgb, frame.intrinsics, stride=2)
    h, w = pred.shape
    camera = colour.intrinsics(w, h) if colour else frame.intrinsics
    predicted = point_cloud(pred, frame.rgb, camera, stride=2)
    centre = np.median(xyz(truth), axis=0)
    views = [render_points(xyz(cloud), colours(cloud), centre) for cloud in (predicted, truth)]
    gap = np.full((views[0].shape[0], 8, 3), 255, dtype=np.uint8)
    return Image.fromarray(np.concatenate([views[0], gap, views[1]], axis=1))
