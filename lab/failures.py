"""Where a fit fails on the views its recording never saw: every held-out view scored, the worst drawn.

A fit's card gives one δ1 over all its held-out frames. What to try next depends on which views
fail and how: a whole view at the wrong distance (its sensor/predicted median ratio far from 1),
wrong shapes at depth steps, or one region the recording never showed (a far corridor, a window).
``failure_report`` scores the published version (its fp32 ONNX) on each held-out view, with the
frames, depth range and colour camera fit scored with (from the run folder's ``fit.json``), and
draws the worst beside the best: the photo, the sensor's depth, the model's, and where δ1 fails.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from contract.colormap import colorize
from contract.errors import UserError
from contract.geometry import ColourCamera
from lab.diagnostics import MedianScaled, delta1_error, near_depth_steps
from recordings.frames import Frame
from recordings.registration import sample_at_colour
from trainer.config import DataSource
from trainer.data.sources import open_source
from trainer.evaluate import evaluate_frames, load_predictor
from trainer.metrics import valid_mask

#: Sensor depths that split a view into near (arm's length: a desk, a chair), mid (across a room) and far (metres).
DEPTH_BANDS_M = (1.5, 3.0)
#: The δ1 map: grey where a pixel passes, red where the model puts it too far, blue too near, black no reading.
PASS, TOO_FAR, TOO_NEAR = (150, 150, 150), (220, 30, 30), (30, 80, 230)


@dataclass
class ViewRecord:
    """What each scored view keeps for the drawing: the photo, the sensor's depth and the model's, on one pixel grid."""

    name: str
    rgb: np.ndarray
    sensor: np.ndarray
    predicted: np.ndarray
    near_steps_failed: float


class KeepViews:
    """A diagnostic for ``evaluate_frames`` that keeps every view it scores, so the worst can be drawn after."""

    name = "views"

    def __init__(self, colour_camera: ColourCamera | None = None) -> None:
        self.views: dict[str, ViewRecord] = {}
        self.colour_camera = colour_camera

    def add(self, pred: np.ndarray, frame: Frame, valid: np.ndarray) -> dict[str, float]:
        fails = valid & (delta1_error(pred, frame.depth) != 0)
        near = near_depth_steps(frame.depth, valid)
        at_steps = float((fails & near).sum() / fails.sum()) if fails.any() else float("nan")
        self.views[frame.name] = ViewRecord(frame.name, self._photo_at_depth_pixels(frame), frame.depth, pred, at_steps)
        return {"near_steps_failed": at_steps}

    def _photo_at_depth_pixels(self, frame: Frame) -> np.ndarray:
        """The photo on the depth image's grid: where the depth is not registered to colour, each depth pixel
        shows the colour pixel that sees its point (as the evaluation reads the prediction), else black."""
        height, width = frame.depth.shape
        rgb = np.asarray(Image.fromarray(frame.rgb).resize((width, height), Image.BILINEAR))
        if self.colour_camera is None:
            return rgb
        channels = [sample_at_colour(rgb[..., c], frame.depth, frame.intrinsics, self.colour_camera) for c in range(3)]
        return np.clip(np.stack(channels, axis=-1).round(), 0, 255).astype(np.uint8)

    def result(self) -> dict[str, int]:
        return {"kept": len(self.views)}


def error_map(pred: np.ndarray, sensor: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The δ1 map as an HxWx3 image: PASS, TOO_FAR or TOO_NEAR at every pixel with a reading, black elsewhere."""
    out = np.zeros((*sensor.shape, 3), dtype=np.uint8)
    error = delta1_error(pred, sensor)
    for value, colour in ((0, PASS), (1, TOO_FAR), (-1, TOO_NEAR)):
        out[valid & (error == value)] = colour
    return out


def failures_by_depth(views: list[ViewRecord], depth_range: tuple[float, float]) -> list[tuple[str, float, float]]:
    """For each band of the sensor's depth: its share of the views' valid pixels, and the share of those that fail δ1.

    NaN where there is nothing to share: no views, or no pixel in the band.

    A view whose median is right can still fail: the near range wrong while the far is right, or the other
    way round. Pooled over ``views``, this says which depths a fit has not learnt.
    """
    edges = (
        depth_range[0],
        *(e for e in DEPTH_BANDS_M if depth_range[0] < e < depth_range[1]),
        depth_range[1],
    )
    counts = np.zeros((len(edges) - 1, 2))
    for view in views:
        valid = valid_mask(view.sensor, *depth_range)
        fails = delta1_error(view.predicted, view.sensor) != 0
        for band, (low, high) in enumerate(pairwise(edges)):
            inside = valid & (view.sensor >= low) & ((view.sensor < high) | (high == edges[-1]))
            counts[band] += (inside.sum(), (inside & fails).sum())
    total = counts[:, 0].sum()
    return [
        (f"{low:g}-{high:g} m", pixels / total if total else np.nan, failed / pixels if pixels else np.nan)
        for (low, high), (pixels, failed) in zip(pairwise(edges), counts, strict=True)
    ]


def share(value: float) -> str:
    """A share to two places, or a dash where there was nothing to share."""
    return "—" if np.isnan(value) else f"{value:.2f}"


def percent(value: float) -> str:
    """A share as a whole percentage, or a dash where there was nothing to share."""
    return "—" if np.isnan(value) else f"{100 * value:.0f}%"


def draw_view(view: ViewRecord, row: dict, depth_range: tuple[float, float]) -> np.ndarray:
    """One row of the picture: photo | sensor depth | predicted depth | δ1 map, with a caption of its scores."""
    valid = valid_mask(view.sensor, *depth_range)
    low, high = np.percentile(view.sensor[valid], [2, 98]) if valid.any() else depth_range
    tiles = [
        view.rgb,
        colorize(np.where(valid, view.sensor, 0.0), low, high),
        colorize(view.predicted, low, high),
        error_map(view.predicted, view.sensor, valid),
    ]
    image = Image.fromarray(np.concatenate(tiles, axis=1))
    caption = (
        f"{view.name}: δ1 {row['delta1']:.3f}, REL {row['rel']:.3f}, sensor/predicted median "
        f"{row['median_ratio']:.2f}, {percent(view.near_steps_failed)} of failures at depth steps; "
        f"colours {low:.2f}-{high:.2f} m"
    )
    ImageDraw.Draw(image).text((6, 4), caption, fill=(255, 255, 255), stroke_width=2, stroke_fill=(0, 0, 0))
    return np.asarray(image)


def failure_report(run: Path, worst: int, out: Path) -> str:
    """Score every held-out view of the fit in ``run``, write ``out/views.md`` and ``out/worst.jpg``; the table."""
    from trainer.fit.state import FitState

    state_path = run / "fit.json"
    if not state_path.is_file():
        raise UserError(f"{run}: no fit.json; give the --out folder of an `rgb2cloud fit`")
    state = FitState.model_validate_json(state_path.read_text())
    if state.published is None:
        raise UserError(f"{run}: this fit has not published a version yet")
    depth_range = (state.config.data.eval_min_m, state.config.data.eval_max_m)
    frames = open_source(DataSource(format="csv", root=run / "holdout.csv"))
    keep = KeepViews(state.colour_camera)
    predict = load_predictor(Path(state.published))
    result, rows, _ = evaluate_frames(
        predict,
        frames,
        min_m=depth_range[0],
        max_m=depth_range[1],
        colour_camera=state.colour_camera,
        diagnostics=[MedianScaled(*depth_range), keep],
    )
    ranked = sorted(rows, key=lambda r: r["delta1"])
    lines = [
        f"{predict.label} on the {len(frames)} held-out views of {state.data}, ground truth in "
        f"[{depth_range[0]}, {depth_range[1]}] m: δ1 {result['delta1']:.3f}, REL {result['rel']:.3f}",
        "",
        "| view | δ1 | REL | sensor/predicted median | failures at depth steps |",
        "|---|---|---|---|---|",
        *(
            f"| {r['name']} | {r['delta1']:.3f} | {r['rel']:.3f} | {r['median_ratio']:.2f} | "
            f"{percent(r['near_steps_failed'])} |"
            for r in ranked
        ),
    ]
    worst_views = [keep.views[r["name"]] for r in ranked[:worst]]
    other_views = [keep.views[r["name"]] for r in ranked[worst:]]
    lines += [
        "",
        f"Where δ1 fails, by the sensor's depth: the {len(worst_views)} worst views, and the other {len(other_views)}",
        "",
        "| sensor depth | the worst: share of pixels | failing | the others: share of pixels | failing |",
        "|---|---|---|---|---|",
        *(
            f"| {band} | {share(w_share)} | {share(w_fail)} | {share(o_share)} | {share(o_fail)} |"
            for (band, w_share, w_fail), (_, o_share, o_fail) in zip(
                failures_by_depth(worst_views, depth_range), failures_by_depth(other_views, depth_range), strict=True
            )
        ),
    ]
    table = "\n".join(lines) + "\n"
    out.mkdir(parents=True, exist_ok=True)
    (out / "views.md").write_text(table)
    drawn = ranked[:worst] + ranked[worst:][-1:]  # the worst, then the best for contrast (if not drawn already)
    picture = np.concatenate([draw_view(keep.views[r["name"]], r, depth_range) for r in drawn], axis=0)
    Image.fromarray(picture).save(out / "worst.jpg", quality=90)
    return table
