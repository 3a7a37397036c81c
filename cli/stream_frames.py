"""Each frame of ``rgb2cloud stream`` as it goes out: fitted to the stream's pixel limit with its camera, or
named and skipped where the client cannot open it, and paced as it was recorded."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from recordings.sources import SourceFrame


@dataclass(frozen=True)
class Sending:
    """A frame as it goes out: the photo at the size sent, and its camera as the stream's options in that
    photo's pixels (None: the service's own camera, from the photo's EXIF or the model's)."""

    frame: SourceFrame
    camera: dict[str, float] | None


@dataclass(frozen=True)
class Unreadable:
    """A photo the client cannot open to fit it to the stream: its frame's name, and why in a few words."""

    name: str
    why: str


def unreadable_reason(error: Exception) -> str:
    """Why Pillow could not open a photo, as the one line that names it says it."""
    from PIL import Image, UnidentifiedImageError

    if isinstance(error, UnidentifiedImageError):
        return "not an image Pillow can read"
    if isinstance(error, Image.DecompressionBombError):
        return f"over Pillow's decompression-bomb limit of {2 * Image.MAX_IMAGE_PIXELS:,} pixels"
    return f"cannot be read ({error})"


def stream_options(first: Sending, given: dict[str, Any]) -> dict[str, Any]:
    """The stream's query: both outputs, raw float depth and raw points, and the first frame's camera (each
    later frame's is sent as it changes)."""
    options = {"output": "both", "depth_encoding": "raw32", "cloud_encoding": "raw"}
    return options | {k: v for k, v in given.items() if v is not None} | (first.camera or {})


class Fitting:
    """Each frame as it is sent: resized to the stream's pixel limit if it is over (said once), with its
    camera in the pixels of the photo sent. A recording's camera comes in each frame (the user's overrides
    already applied in the recording's pixels by its reader); a camera's, video's or photos' is what the
    user gave in their frames' pixels, only the values given, so the service fills in the rest as ``/depth``
    does."""

    def __init__(self, max_pixels: int, given: dict[str, float], say: Callable[[str], None]):
        self.max_pixels, self.given, self.say, self.said = max_pixels, given, say, False

    def __call__(self, frame: SourceFrame) -> Sending | Unreadable:
        """The frame as it goes out, or why it cannot: a photo that is no image, is cut off where it must be
        decoded here (to be resized), or is over Pillow's decompression-bomb limit."""
        from PIL import Image

        try:
            frame, (width, height), (sx, sy) = self._sized(frame)
        except (OSError, ValueError, Image.DecompressionBombError) as e:  # OSError: unidentified or truncated
            return Unreadable(frame.name, unreadable_reason(e))
        return self._with_camera(frame, width, height, sx, sy)

    def _sized(self, frame: SourceFrame) -> tuple[SourceFrame, tuple[int, int], tuple[float, float]]:
        """The photo within the stream's pixels (Pillow's work alone, whose errors make it unreadable): the frame
        as sent, its size, and the scale of each axis."""
        import dataclasses
        import io

        from PIL import Image

        with Image.open(io.BytesIO(frame.data)) as im:
            width, height = im.size
            sx = sy = 1.0
            if width * height > self.max_pixels:
                scale = (self.max_pixels / (width * height)) ** 0.5
                size = max(1, int(width * scale)), max(1, int(height * scale))
                if not self.said:
                    self.say(
                        f"photos of {width}x{height} are over the stream's {self.max_pixels:,} pixels: sent at "
                        f"{size[0]}x{size[1]}, their camera scaled to match"
                    )
                    self.said = True
                out = io.BytesIO()
                # Its EXIF goes with it: the service turns it upright and reads its focal length (which
                # scales with the stored size) as it would the photo's own.
                resized = im.convert("RGB").resize(size, Image.Resampling.LANCZOS)
                resized.save(out, format="JPEG", quality=90, exif=im.getexif())
                frame = dataclasses.replace(frame, data=out.getvalue())
                sx, sy = size[0] / width, size[1] / height
                width, height = size
        return frame, (width, height), (sx, sy)

    def _with_camera(self, frame: SourceFrame, width: int, height: int, sx: float, sy: float) -> Sending:
        """The frame with its camera in the pixels of the photo sent."""
        import dataclasses

        from contract.geometry import resized_coordinate

        if frame.camera is not None:
            k = frame.camera.resized(width, height)
            return Sending(dataclasses.replace(frame, camera=k), {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy})
        given = dict(self.given)
        if ("fx" in given) != ("fy" in given):  # as /depth takes one focal length: both, in the photo's pixels
            given["fx"] = given["fy"] = given.get("fx", given.get("fy"))
        scaled = {
            "fx": lambda v: v * sx,
            "fy": lambda v: v * sy,
            "cx": lambda v: resized_coordinate(v, sx),
            "cy": lambda v: resized_coordinate(v, sy),
        }
        return Sending(frame, {key: scaled[key](v) for key, v in given.items()} or None)


def paced(frames: Iterable[SourceFrame], rate: float) -> Iterator[SourceFrame]:
    """Frames no sooner than their stamps say, at ``rate`` times their recorded pace (as ``ros2 bag play``
    plays); ``rate`` 0 lets them go as fast as they are taken."""
    began: tuple[float, int] | None = None
    for frame in frames:
        if rate > 0:
            if began is None:
                began = (time.monotonic(), frame.stamp_ns)
            wait = began[0] + (frame.stamp_ns - began[1]) / 1e9 / rate - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        yield frame
