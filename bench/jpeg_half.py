"""A JPEG shown at exactly half its size, decoded at half: the same depth as its full decode's 2x2 mean?

    python bench/jpeg_half.py runs/bench-levers/runs/live-half-aims-lab \\
        runs/bench-levers/runs/live-half-mosd-tabletop [--kitchen runs/live-kitchen-0/checkpoints/last.pt ...] \\
        [--repeats 50]

Where the generator sees a JPEG at exactly half its width and height, the service decodes it at half (libjpeg's
DCT scaling, ``app.imaging.Upload.rgb``) on every route, while ``rgb2cloud evaluate``, fit's held-out table and
training's validation decode every photo in full and take each 2x2 block's mean (``contract.resample``).
This scores each model on its held-out JPEG frames both ways, with the same metrics and the same generator (ONNX
Runtime fp32 for a version, eager for a checkpoint), and times both decodes on the first frame, taking turns.
Each argument is the run folder of an `rgb2cloud fit --pixels` (its published version, on fit.json's held-out
views); ``--kitchen`` takes 320x240 kitchen models (version folders or checkpoints), scored on the 7-Scenes test
frames as the bundled model's card scored them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from working_scale import Site, fit_site, kitchen_site

from app.imaging import open_upload
from contract.geometry import Intrinsics
from contract.resample import depth_to_photo, generator_size, to_model_camera
from harness.timing import interleaved_ms
from trainer.evaluate import FramePredict, Predictor, evaluate_frames
from trainer.machine import cpu_description

BUNDLED = Path(__file__).resolve().parents[1] / "weights/rgb2cloud-7scenes/0.9.1"
#: Any photo the recordings hold: the service's own pixel limit does not apply to a recording.
NO_LIMIT = 1 << 40


def half_decoded(model: Predictor, paths: dict[int, Path]) -> FramePredict:
    """The model's depth for each frame's JPEG file decoded at half, as the service decodes it.

    ``paths`` maps each frame's photo (by ``id``) to its file; the file's full decode must be that photo.
    """

    def predict(rgb: np.ndarray, photo: Intrinsics) -> np.ndarray:
        path = paths[id(rgb)]
        size = generator_size(photo, model.camera, model.max_pixels)[0]
        if not np.array_equal(open_upload(path.read_bytes(), NO_LIMIT).rgb(), rgb):
            raise SystemExit(f"{path}: its decode is not the frame the recording reader gave")
        half = open_upload(path.read_bytes(), NO_LIMIT).rgb(size)
        if half.shape[:2] != (size[1], size[0]):
            raise SystemExit(f"{path}: not a JPEG at exactly twice the generator's {size[0]}x{size[1]}")
        return depth_to_photo(model.run(half), photo)

    return predict


def site_row(site: Site, repeats: int) -> str:
    """The site's metrics with each decode, and both decodes' times on its first frame."""
    reader = site.frames
    if not hasattr(reader, "pairs"):
        raise SystemExit(f"{site.label}: scores recordings of image files only")
    frames = [reader[i] for i in range(len(reader))]
    paths = {id(frame.rgb): pair.rgb for frame, pair in zip(frames, reader.pairs, strict=True)}
    model, first, data = site.model, frames[0], reader.pairs[0].rgb.read_bytes()
    h, w = first.depth.shape
    photo = site.colour_camera.intrinsics(w, h) if site.colour_camera else first.intrinsics
    size = generator_size(photo, model.camera, model.max_pixels)[0]
    times = interleaved_ms(
        {
            "full": lambda: to_model_camera(open_upload(data, NO_LIMIT).rgb(), photo, model.camera, model.max_pixels),
            "half": lambda: open_upload(data, NO_LIMIT).rgb(size),
        },
        repeats,
    )
    scores = {}
    for how, predict in (("full", model), ("half", half_decoded(model, paths))):
        scores[how], _, _ = evaluate_frames(
            predict, frames, min_m=site.depth_range[0], max_m=site.depth_range[1], colour_camera=site.colour_camera
        )
    full, half = scores["full"], scores["half"]
    return (
        f"| {site.label} | {len(frames)} | {full['delta1']:.4f} | {half['delta1']:.4f} | "
        f"{half['delta1'] - full['delta1']:+.4f} | {full['rel']:.4f} | {half['rel']:.4f} | "
        f"{times['full']:.2f} | {times['half']:.2f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="*", type=Path, help="run folders of `rgb2cloud fit --pixels`")
    parser.add_argument("--kitchen", nargs="*", type=Path, default=[], help="320x240 kitchen versions or checkpoints")
    parser.add_argument("--repeats", type=int, default=50, help="timed decodes of each kind")
    args = parser.parse_args()
    sites = [kitchen_site(BUNDLED, model) for model in args.kitchen] + [fit_site(run) for run in args.runs]
    if not sites:
        raise SystemExit("nothing to score: give fit run folders or --kitchen models")
    print(f"Machine: {cpu_description()}; ONNX Runtime fp32 (versions) or eager (checkpoints)\n")
    print(
        "| model, held-out frames | frames | δ1, full decode + 2x2 mean | δ1, decoded at half | change | "
        "REL, full | REL, half | full decode + 2x2 mean ms | decode at half ms |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for site in sites:
        print(site_row(site, args.repeats), flush=True)


if __name__ == "__main__":
    main()
