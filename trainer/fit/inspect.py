"""Look at a recording before spending the budget on it: units, holes, sizes, registration.

A wrong ``depth_scale`` or depth that is not in the photo's view wastes a whole fit
and gives a model that is confidently wrong. Both show in a dozen frames, so they are
checked first: implausible units are an error that names the likely scale, and depth
from a separate depth camera is registered to the colour camera (the same fit as
``rgb2cloud calibrate``), with the alignment reported before and after.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np
from PIL import Image

from contract.errors import UserError
from contract.geometry import ColourCamera
from recordings.formats import Recording
from recordings.frames import Frame, RecordedPair, read_pair
from recordings.registration import alignment, fit_colour_camera
from trainer.data.transforms import resize_frame

#: Median depth a room-scale recording has, in metres; outside it the units are wrong.
PLAUSIBLE_MEDIAN_M = (0.2, 20.0)
#: Raw depth units per metre that sensors and tools use.
COMMON_DEPTH_SCALES = (1.0, 10.0, 100.0, 1000.0, 4000.0, 5000.0, 10000.0)
#: A fitted colour camera must align colour edges with depth steps this much better (relative)
#: than the depth camera itself before the depth is treated as unregistered. Measured: 7-Scenes'
#: raw Kinect pairs gain 73% (``rgb2cloud calibrate ../shared/data/7scenes-redkitchen``: 0.127 as
#: recorded, 0.219 fitted); mosd-tabletop, registered in hardware, gains 17% in ``rgb2cloud fit``'s
#: check (0.271, 0.316), which is the edge measure's noise, not an offset.
REGISTRATION_GAIN = 0.30


@dataclass
class Inspection:
    """What a sample of the recording's frames shows."""

    pairs: int
    skipped: list[tuple[str, str]]
    sizes: Counter
    depth_range_m: tuple[float, float]
    median_m: float
    holes: float
    alignment_as_recorded: float | None = None
    alignment_registered: float | None = None
    colour_camera: ColourCamera | None = None

    def lines(self) -> list[str]:
        """The short report ``fit`` prints."""
        sampled = sum(self.sizes.values())
        sizes = ", ".join(f"{w}x{h} ({n} of {sampled} sampled frames)" for (w, h), n in self.sizes.most_common())
        out = [f"pairs: {self.pairs} found, {len(self.skipped)} skipped"]
        out += [f"  skipped {name}: {why}" for name, why in self.skipped[:10]]
        if len(self.skipped) > 10:
            out.append(f"  ... and {len(self.skipped) - 10} more")
        low, high = self.depth_range_m
        out += [
            f"image sizes: {sizes}",
            f"depth: {low:.2f}-{high:.2f} m, median {self.median_m:.2f} m, holes {100 * self.holes:.0f}% of pixels",
        ]
        if self.alignment_as_recorded is not None:
            verdict = (
                f"depth is not in the photo's view: registered to colour camera {self.colour_camera.flow()}"
                if self.colour_camera
                else "depth is taken as in the photo's view already"
            )
            out.append(
                f"registration: colour edges on depth steps {self.alignment_as_recorded:.3f} as recorded, "
                f"{self.alignment_registered:.3f} fitted; {verdict}"
            )
        return out


#: What a damaged image file raises when decoded (PIL: OSError for truncated data, SyntaxError for a broken
#: PNG chunk, ValueError for impossible sizes), and a pair whose photo and depth differ in size.
DAMAGE = (OSError, SyntaxError, ValueError, UserError)


def readable(recording: Recording) -> Recording:
    """The recording without the pairs whose files cannot be decoded, which join its skipped list, named.

    Every pair is decoded once here, so one damaged file among hundreds costs its own pair and is
    named in the summary, instead of stopping training half-way. Depth that is not depth (8-bit or
    colour PNGs, a preview saved in place of the data) is refused outright: no frame of such a
    recording can be right.
    """
    kept, damaged = [], []
    for pair in recording.pairs:
        try:
            with Image.open(pair.depth) as im:
                mode = im.mode
            if mode in DEPTH_MODES:
                read_pair(pair)
        except DAMAGE as e:
            damaged.append((pair.name, str(e) if isinstance(e, UserError) else "damaged: not a readable image"))
            continue
        if mode not in DEPTH_MODES:
            raise UserError(
                f"{pair.depth}: an {DESCRIBED_MODES.get(mode, mode)} image, not 16-bit depth: fit needs the "
                "depth camera's 16-bit PNGs (a saved preview holds no distances)"
            )
        kept.append(pair)
    if not damaged:
        return recording
    return replace(recording, pairs=kept, skipped=[*recording.skipped, *damaged])


#: PIL modes of single-channel 16- and 32-bit images: what depth PNGs hold.
DEPTH_MODES = ("I;16", "I;16B", "I;16L", "I", "F")
DESCRIBED_MODES = {
    "L": "8-bit greyscale",
    "P": "8-bit palette",
    "1": "1-bit",
    "RGB": "8-bit colour",
    "RGBA": "8-bit colour",
}


def sample_frames(pairs: list[RecordedPair], count: int) -> list[Frame]:
    """Up to ``count`` frames spread evenly over ``pairs``."""
    picks = np.unique(np.linspace(0, len(pairs) - 1, min(count, len(pairs))).round().astype(int))
    return [read_pair(pairs[i]) for i in picks]


def inspect_recording(recording: Recording, sample: int = 12, registration: str = "auto") -> Inspection:
    """Inspect a sample of frames; raise UserError on units that cannot be right.

    ``registration``: ``auto`` fits a colour camera and registers only if it aligns
    clearly better; ``yes`` always registers with the fit; ``no`` never checks.
    """
    frames = sample_frames(recording.pairs, sample)
    depth = np.concatenate([f.depth.ravel() for f in frames])
    valid = depth[depth > 0]
    if valid.size == 0:
        raise UserError(f"{recording.root}: the sampled depth images hold no readings at all")
    median = float(np.median(valid))
    scale = recording.pairs[0].depth_scale
    if not PLAUSIBLE_MEDIAN_M[0] <= median <= PLAUSIBLE_MEDIAN_M[1]:
        likely = min(COMMON_DEPTH_SCALES, key=lambda s: abs(math.log(median * scale / s / 2.0)))
        raise UserError(
            f"{recording.root}: the median depth is {median:.3g} m with depth_scale {scale:g} units per metre, "
            f"not a room's {PLAUSIBLE_MEDIAN_M[0]}-{PLAUSIBLE_MEDIAN_M[1]} m; the units are likely "
            f"--depth-scale {likely:g} (median {median * scale / likely:.2f} m)"
        )
    result = Inspection(
        pairs=len(recording.pairs),
        skipped=recording.skipped,
        sizes=Counter((f.rgb.shape[1], f.rgb.shape[0]) for f in frames),
        depth_range_m=(float(np.percentile(valid, 1)), float(np.percentile(valid, 99))),
        median_m=median,
        holes=float(1 - valid.size / depth.size),
    )
    if registration != "no":
        _check_registration(result, frames[: min(8, len(frames))], always=registration == "yes")
    return result


def _check_registration(result: Inspection, frames: list[Frame], always: bool) -> None:
    """Fit the colour camera at half resolution; keep it if it aligns clearly better (or ``always``)."""
    small = [resize_frame(f, f.depth.shape[0] // 2, f.depth.shape[1] // 2) for f in frames]
    k = small[0].intrinsics
    same = ColourCamera(fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy)
    fitted, score = fit_colour_camera(small, same)
    result.alignment_as_recorded = alignment(small, same)
    result.alignment_registered = score
    if always or score > result.alignment_as_recorded * (1 + REGISTRATION_GAIN):
        result.colour_camera = fitted.resized(2.0)
