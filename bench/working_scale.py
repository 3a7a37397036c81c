"""A cheaper generator for live video: each photo shown to the network at a fraction of the model's focal length.

    python bench/working_scale.py runs/bench-levers/runs/from-0-9-0-aims-lab \\
        runs/bench-levers/runs/from-0-9-0-mosd-tabletop [--kitchen weights/rgb2cloud-7scenes/0.9.1] \\
        [--scales 1 0.85 0.7 0.5] [--repeats 20]

Each argument is the run folder of an `rgb2cloud fit`. Its published version is scored on its held-out views as
fit scored them (fit.json's frames, depth range and colour camera; ONNX Runtime fp32), and ``--kitchen``'s
version on the 7-Scenes test frames as its card scored them, with the photo resampled
to ``scale`` times the model's focal length, so that the generator sees ``scale²`` of its pixels. A network that
learned one camera sees a photo shrunk by ``scale`` as if everything were ``1/scale`` times farther, so each
scale is scored twice: the depth as the network gave it, and multiplied by ``scale`` (the canonical camera's
correction, as Metric3D makes it). The generator's median time on the first held-out photo at each size is
timed in the same run. Issue 70's rule: a cheaper variant is kept only if its held-out δ1 on both development
sites is within 0.005 of the full one.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contract.card import load_card
from contract.geometry import ColourCamera, Intrinsics
from contract.resample import depth_at_photo, to_model_camera
from harness.timing import interleaved_ms
from recordings.frames import Frame
from trainer.config import DataSource
from trainer.data.sources import open_source
from trainer.evaluate import FramePredict, Predictor, evaluate_frames, load_predictor
from trainer.fit.state import FitState
from trainer.machine import cpu_description

WITHIN = 0.005
SEVEN_SCENES = Path(__file__).resolve().parents[2] / "shared/data/7scenes-redkitchen"


def scaled_camera(model: Predictor, scale: float) -> Intrinsics:
    """The model's camera with ``scale`` times its focal length (and its image ``scale`` times as wide)."""
    return model.camera.resized(round(model.camera.width * scale), round(model.camera.height * scale))


def at_scale(model: Predictor, scale: float, corrected: bool) -> FramePredict:
    """The model's depth for a photo shown to the generator at ``scale`` times the model's focal length."""
    camera = scaled_camera(model, scale)

    def predict(rgb: np.ndarray, photo: Intrinsics) -> np.ndarray:
        depth, ratio = depth_at_photo(model.run, rgb, photo, camera, model.max_pixels)
        # The focal ratio the generator saw: the scale, and any further shrink to max_pixels.
        return depth * (ratio * camera.fx / model.camera.fx) if corrected else depth

    return predict


@dataclass(frozen=True)
class Site:
    """A model and the held-out frames it is scored on, as its own table scored it."""

    label: str
    model: Predictor
    frames: Sequence[Frame]
    depth_range: tuple[float, float]
    colour_camera: ColourCamera | None


def fit_site(run: Path) -> Site:
    """The version the fit in ``run`` published, on its held-out views (fit.json's range and colour camera)."""
    state = FitState.model_validate_json((run / "fit.json").read_text())
    if state.published is None:
        raise SystemExit(f"{run}: this fit has not published a version")
    frames = open_source(DataSource(format="csv", root=run / "holdout.csv"))
    depth_range = (state.config.data.eval_min_m, state.config.data.eval_max_m)
    return Site(run.name, load_predictor(Path(state.published)), frames, depth_range, state.colour_camera)


def kitchen_site(version: Path, model: Path | None = None) -> Site:
    """A 7-Scenes version on the test split as its card scored it (frames 850-999, the card's colour camera);
    ``model`` (a checkpoint, or another version) scored in its place the same way, if given."""
    card = load_card(version)
    test = next((m for m in card.metrics if m.split.startswith("7scenes-redkitchen 850-999")), None)
    if test is None:
        raise SystemExit(f"{version}: its card has no 7-Scenes test split (7scenes-redkitchen 850-999) to score on")
    frames = open_source(DataSource(format="7scenes", root=SEVEN_SCENES, frames="850-999"))
    predictor = load_predictor(model or version)
    label = f"{predictor.label if model else f'{card.name} {card.version}'}, 7-Scenes test"
    return Site(label, predictor, frames, test.depth_range_m, test.colour_camera)


def site_rows(site: Site, scales: list[float], repeats: int) -> list[str]:
    """One table row per scale and depth reading for ``site``."""
    model, first = site.model, site.frames[0]
    h, w = first.depth.shape
    intrinsics = site.colour_camera.intrinsics(w, h) if site.colour_camera else first.intrinsics
    seen: dict[float, np.ndarray] = {}
    calls = {}
    for scale in scales:
        camera = scaled_camera(model, scale)
        seen[scale] = to_model_camera(first.rgb, intrinsics, camera, model.max_pixels)[0]
        calls[f"generator {scale:g}"] = lambda rgb=seen[scale]: model.run(rgb)
        calls[f"frame {scale:g}"] = lambda camera=camera: depth_at_photo(
            model.run, first.rgb, intrinsics, camera, model.max_pixels
        )
    times = interleaved_ms(calls, repeats)

    rows, full = [], None
    for scale in scales:
        for corrected in (False, True) if scale != 1 else (False,):
            result, _, _ = evaluate_frames(
                at_scale(model, scale, corrected),
                site.frames,
                min_m=site.depth_range[0],
                max_m=site.depth_range[1],
                colour_camera=site.colour_camera,
            )
            full = result["delta1"] if full is None else full
            size = f"{seen[scale].shape[1]}x{seen[scale].shape[0]}"
            how = "full (as served)" if scale == 1 else ("x scale" if corrected else "as given")
            delta = result["delta1"] - full
            verdict = "" if scale == 1 else ("within" if delta >= -WITHIN else "loses")
            rows.append(
                f"| {site.label} | {scale:g} | {size} | {times[f'generator {scale:g}']:.1f} | "
                f"{times[f'frame {scale:g}']:.1f} | {how} | {result['delta1']:.3f} | "
                f"{result['rel']:.3f} | {delta:+.3f} | {verdict} |"
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="*", type=Path, help="run folders of `rgb2cloud fit`")
    parser.add_argument("--kitchen", type=Path, help="also a 7-Scenes version folder on the test split")
    parser.add_argument("--scales", nargs="+", type=float, default=[1.0, 0.85, 0.7, 0.5])
    parser.add_argument("--repeats", type=int, default=20, help="timed generator runs per size")
    args = parser.parse_args()
    if 1.0 not in args.scales or any(not 0 < s <= 1 for s in args.scales):
        raise SystemExit("--scales: each in (0, 1], and 1 among them (the full generator every row is against)")
    scales = sorted(args.scales, reverse=True)

    print(
        f"Machine: {cpu_description()}. ONNX Runtime fp32; timed on each model's first held-out photo: the generator "
        "alone, and with the photo's resample to the scale and the depth's back to the photo's pixels.\n"
    )
    print(
        "| model | scale | photo shown at | generator ms | with both resamples ms | depth | held-out δ1 | REL | Δ δ1 "
        "| rule (within 0.005) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    sites = [kitchen_site(args.kitchen)] if args.kitchen else []
    for site in [*sites, *map(fit_site, args.runs)]:
        for row in site_rows(site, scales, args.repeats):
            print(row, flush=True)


if __name__ == "__main__":
    main()
