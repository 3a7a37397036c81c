"""Depth cameras beside colour cameras: registering one to the other, and fitting how.

Kinect v1 recordings such as Microsoft 7-Scenes store raw depth in the depth
(infrared) camera's frame, not the colour camera's: the two lenses differ (the
colour camera sees a wider view) and sit a few centimetres apart. A network
that reads a photo can only place an edge where the photo shows it, so it is
trained on depth moved into the colour camera (``depth_to_colour``), and its
colour-frame prediction is compared with a raw ground-truth pixel at the colour
pixel that sees the same 3D point (``sample_at_colour``). Both need the
ground-truth depth itself: where a point lands depends on how far it is.

The model is a pinhole colour camera translated by ``baseline_m`` along the
depth camera's x axis and turned by ``roll_deg`` about its optical axis (a turn
about the other two axes is, this close to the centre, a shift of the principal
point, which the fit already has); ``fit_colour_camera`` finds it from
the data by aligning colour edges with depth steps, so a number here always
comes from a command (``rgb2cloud calibrate``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image
from scipy import ndimage

from contract.geometry import ColourCamera, Intrinsics
from recordings.frames import Frame


def colour_coordinates(depth: np.ndarray, depth_camera: Intrinsics, colour: ColourCamera) -> tuple[np.ndarray, ...]:
    """Colour-image (x, y) and colour-camera z of every depth pixel; NaN where depth is 0."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = np.where(depth > 0, depth, np.nan).astype(np.float64)
    x = (u - depth_camera.cx) / depth_camera.fx - colour.baseline_m / z
    y = (v - depth_camera.cy) / depth_camera.fy
    if colour.roll_deg:
        c, s = np.cos(np.radians(colour.roll_deg)), np.sin(np.radians(colour.roll_deg))
        x, y = c * x - s * y, s * x + c * y
    return colour.fx * x + colour.cx, colour.fy * y + colour.cy, z


def depth_to_colour(depth: np.ndarray, depth_camera: Intrinsics, colour: ColourCamera) -> np.ndarray:
    """Depth as the colour camera would see it; nearest wins, 0 where no depth pixel lands.

    Nothing is filled in: a colour pixel that no depth pixel reaches (beyond the depth
    camera's view, or behind an edge only the colour camera sees past) has no
    ground truth, and training masks it. It is ``reproject_depth`` with the pair's rigid
    transform (``colour_extrinsics``): one reprojection for every registration.
    """
    h, w = depth.shape
    rotation, translation = colour_extrinsics(colour)
    return reproject_depth(depth, depth_camera, colour.intrinsics(w, h), rotation, translation)


def colour_extrinsics(colour: ColourCamera) -> tuple[np.ndarray, np.ndarray]:
    """(rotation, translation) from the depth camera's frame into a ``ColourCamera``'s, as ``reproject_depth`` takes.

    ``colour_coordinates``' model as a rigid transform: the colour camera sits ``baseline_m`` along the
    depth camera's x axis (so a point's x there is ``x - baseline``), turned by ``roll_deg`` about the
    optical axis. Neither changes a point's z.
    """
    c, s = np.cos(np.radians(colour.roll_deg)), np.sin(np.radians(colour.roll_deg))
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rotation, rotation @ np.array([-colour.baseline_m, 0.0, 0.0])


def reproject_depth(
    depth: np.ndarray,
    depth_camera: Intrinsics,
    colour_camera: Intrinsics,
    rotation: np.ndarray,
    translation: np.ndarray,
) -> np.ndarray:
    """Depth moved into another camera by a full rigid transform, at that camera's size; 0 where none lands.

    ``rotation`` (3x3) and ``translation`` (metres) map a point from the depth camera's frame into
    the colour camera's: ``p_colour = rotation @ p_depth + translation``, as a bag's extrinsics give
    them. The nearest point wins each colour pixel, and nothing is interpolated across a depth step.
    Where the colour camera sees a narrower view than the depth camera (a longer focal length,
    as on RealSense cameras), depth pixels land farther apart than colour pixels: each depth pixel
    is then split into ``n x n`` samples of its own depth before it is projected, so no pinholes
    open inside a surface while an edge stays where the depth had it.
    """
    n = max(1, int(np.ceil(max(colour_camera.fx / depth_camera.fx, colour_camera.fy / depth_camera.fy) - 1e-9)))
    h, w = depth.shape
    offsets = (np.arange(n) + 0.5) / n - 0.5
    v = (np.arange(h)[:, None] + offsets[None, :]).ravel()  # every sample row, in depth pixels
    u = (np.arange(w)[:, None] + offsets[None, :]).ravel()
    z = np.repeat(np.repeat(depth.astype(np.float64), n, axis=0), n, axis=1)
    vv, uu = np.meshgrid(v, u, indexing="ij")
    valid = z > 0
    z, uu, vv = z[valid], uu[valid], vv[valid]
    points = np.stack([(uu - depth_camera.cx) / depth_camera.fx * z, (vv - depth_camera.cy) / depth_camera.fy * z, z])
    moved = np.asarray(rotation, np.float64) @ points + np.asarray(translation, np.float64).reshape(3, 1)
    zc = moved[2]
    ahead = zc > 0
    col = np.rint(colour_camera.fx * moved[0, ahead] / zc[ahead] + colour_camera.cx)
    row = np.rint(colour_camera.fy * moved[1, ahead] / zc[ahead] + colour_camera.cy)
    zc = zc[ahead]
    inside = (col >= 0) & (col < colour_camera.width) & (row >= 0) & (row < colour_camera.height)
    flat = (row[inside] * colour_camera.width + col[inside]).astype(np.int64)
    return nearest_surface(flat, zc[inside], colour_camera.height, colour_camera.width)


def nearest_surface(flat: np.ndarray, z: np.ndarray, height: int, width: int) -> np.ndarray:
    """A ``height`` x ``width`` depth image where each pixel holds the least ``z`` landing on it (0: none).

    A z-buffer with ``np.minimum.at``, which combines repeated indices by definition; a plain
    fancy-index assignment leaves the winner of a repeated index to an order NumPy does not define.
    """
    out = np.full(height * width, np.inf, dtype=np.float32)
    np.minimum.at(out, flat, z.astype(np.float32))
    out[np.isinf(out)] = 0.0
    return out.reshape(height, width)


#: Depth samples within this relative spread of the nearest are one surface; wider is a step. On the real
#: iPhone frame (../shared/data/captures/iphone-lidar) the edge score (``alignment``, at half size) was
#: 0.335 at 2%, 0.311 at 5%, 0.286 at 10%; bilinear 0.342 (which blends across steps), nearest 0.258.
SURFACE_SPREAD = 0.02


def upsample_depth(depth: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """Depth from a coarse grid over the same view (a phone's LiDAR) at the photo's size, no depth invented.

    Each photo pixel sits among four depth samples. Where they hold depth within ``SURFACE_SPREAD``
    of each other they are one surface, and the pixel takes their bilinear blend (holes left out).
    Where they straddle a depth step, the pixel takes the sample whose colour (the photo averaged
    down to the depth grid) is nearest its own, blended only with the samples on that sample's
    surface. So a step lands on the photo's edge, and no pixel gets a depth between two surfaces.
    0 where no sample has depth.
    """
    h, w = rgb.shape[:2]
    dh, dw = depth.shape
    y = np.clip((np.arange(h) + 0.5) * dh / h - 0.5, 0, dh - 1)
    x = np.clip((np.arange(w) + 0.5) * dw / w - 0.5, 0, dw - 1)
    y0, x0 = np.minimum(y.astype(int), max(dh - 2, 0)), np.minimum(x.astype(int), max(dw - 2, 0))
    y1, x1 = np.minimum(y0 + 1, dh - 1), np.minimum(x0 + 1, dw - 1)
    fy, fx = (y - y0)[:, None], (x - x0)[None, :]
    corners = [(y0, x0), (y0, x1), (y1, x0), (y1, x1)]
    values = np.stack([depth[r][:, c] for r, c in corners]).astype(np.float32)  # 4 x h x w
    weights = np.stack([(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx]).astype(np.float32)
    valid = (values > 0) & (weights > 0)
    low = np.where(valid, values, np.inf).min(axis=0)
    high = np.where(valid, values, 0).max(axis=0)
    one_surface = high <= low * (1 + SURFACE_SPREAD)
    # At a step: the sample whose colour (the photo averaged down to the depth grid) is nearest the
    # pixel's own, and the samples on its surface.
    small = np.asarray(Image.fromarray(rgb).resize((dw, dh), Image.BOX), dtype=np.float32)
    distance = np.stack([np.abs(small[r][:, c] - rgb).sum(axis=-1) for r, c in corners])
    distance[~valid] = np.inf
    chosen = np.take_along_axis(values, distance.argmin(axis=0)[None], axis=0)
    on_chosen = valid & (np.abs(values - chosen) <= chosen * SURFACE_SPREAD)
    members = np.where(one_surface[None], valid, on_chosen)
    kept = weights * members
    total = kept.sum(axis=0)
    return np.where(total > 0, (values * kept).sum(axis=0) / np.maximum(total, 1e-12), 0).astype(np.float32)


def register_frame(frame: Frame, colour: ColourCamera) -> Frame:
    """The frame with its depth moved into the colour camera, and the colour camera's intrinsics."""
    h, w = frame.depth.shape
    return Frame(frame.rgb, depth_to_colour(frame.depth, frame.intrinsics, colour), colour.intrinsics(w, h), frame.name)


def sample_at_colour(
    image: np.ndarray, depth: np.ndarray, depth_camera: Intrinsics, colour: ColourCamera
) -> np.ndarray:
    """``image`` (colour frame) read at each depth pixel's colour pixel, bilinear; 0 where none."""
    xc, yc, z = colour_coordinates(depth, depth_camera, colour)
    h, w = image.shape
    inside = np.isfinite(z) & (xc >= 0) & (xc <= w - 1) & (yc >= 0) & (yc <= h - 1)
    out = np.zeros(depth.shape, dtype=np.float32)
    out[inside] = ndimage.map_coordinates(image.astype(np.float32), [yc[inside], xc[inside]], order=1)
    return out


def _depth_steps(depth: np.ndarray) -> np.ndarray:
    """Log-depth gradient magnitude, zero near missing depth (its border is not a step)."""
    filled = np.where(depth > 0, depth, np.median(depth[depth > 0]))
    log = np.log(filled)
    steps = np.hypot(ndimage.sobel(log, 0), ndimage.sobel(log, 1))
    steps[ndimage.binary_dilation(depth <= 0, iterations=2)] = 0
    return steps


def _colour_edges(rgb: np.ndarray) -> np.ndarray:
    grey = ndimage.gaussian_filter(rgb.astype(np.float32).mean(axis=2), 1.0)
    return np.hypot(ndimage.sobel(grey, 0), ndimage.sobel(grey, 1))


def alignment(frames: Sequence[Frame], colour: ColourCamera) -> float:
    """Mean normalised correlation between depth steps and the colour edges at their colour pixels."""
    scores = []
    for frame in frames:
        steps = _depth_steps(frame.depth)
        edges = sample_at_colour(_colour_edges(frame.rgb), frame.depth, frame.intrinsics, colour)
        denominator = np.sqrt((steps * steps).sum() * (edges * edges).sum())
        scores.append(float((steps * edges).sum() / denominator) if denominator > 0 else 0.0)
    return float(np.mean(scores))


#: Coordinate search: per parameter, the step sizes tried in turn (coarse to fine), sized for
#: 640x480 images (a pixel or less at the last).
SEARCH_ROUNDS = 3
SEARCH_STEPS = {
    "fx": (16.0, 4.0, 1.0),
    "cx": (8.0, 2.0, 0.5),
    "cy": (8.0, 2.0, 0.5),
    "baseline_m": (0.02, 0.005, 0.001),
    "roll_deg": (0.5, 0.15, 0.05),
}


def fit_colour_camera(frames: Sequence[Frame], start: ColourCamera) -> tuple[ColourCamera, float]:
    """The colour camera that best aligns colour edges with depth steps, and its alignment.

    A coordinate search from ``start``: for each step size, each parameter moves
    by +-step while that helps. fy follows fx (square pixels), so five numbers
    are fitted: the focal length, the principal point, the baseline and the roll.
    """
    best = start
    best_score = alignment(frames, best)
    for round_ in range(SEARCH_ROUNDS):
        improved = True
        while improved:
            improved = False
            for name, steps in SEARCH_STEPS.items():
                step = steps[round_]
                for sign in (1.0, -1.0):
                    value = getattr(best, name) + sign * step
                    changes = {name: value, "fy": value} if name == "fx" else {name: value}
                    candidate = best.model_copy(update=changes)
                    score = alignment(frames, candidate)
                    if score > best_score:
                        best, best_score, improved = candidate, score, True
                        break
    return best, best_score


def calibrate_sequence(root: Path, frames: str, every: int, fx: float, others: dict[str, ColourCamera]) -> list[str]:
    """``rgb2cloud calibrate``: fit the colour camera of a 7-Scenes sequence; the lines to print.

    The fit starts from the depth camera's own intrinsics with focal length ``fx``;
    each of ``others`` (label -> camera) is scored on the same frames for comparison.
    """
    from recordings.frames import parse_frame_ranges
    from recordings.sevenscenes import SevenScenesReader

    chosen = parse_frame_ranges(frames)[::every]
    reader = SevenScenesReader(root, ",".join(str(n) for n in chosen))
    sample = [reader[i] for i in range(len(reader))]
    depth_camera = sample[0].intrinsics
    unregistered = ColourCamera(fx=depth_camera.fx, fy=depth_camera.fy, cx=depth_camera.cx, cy=depth_camera.cy)
    fitted, score = fit_colour_camera(sample, unregistered.model_copy(update={"fx": fx, "fy": fx}))
    return [
        f"{len(sample)} frames of {frames}, every {every}th",
        f"alignment as recorded (same camera): {alignment(sample, unregistered):.4f}",
        *(f"alignment of {label}: {alignment(sample, camera):.4f}" for label, camera in others.items()),
        f"alignment fitted: {score:.4f}",
        f"colour_camera: {fitted.flow()}",
    ]
