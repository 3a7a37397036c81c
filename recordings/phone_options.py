"""What a phone LiDAR export's reader is told: which frames to write, which depth to trust, camera overrides.

Stray Scanner and Record3D exports share these; both write their frames with ``PairWriter``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from recordings.folders import CameraFile
from recordings.frames import DEFAULT_MAX_FRAMES, kept_note, spread

#: Depth pixels of lower confidence are dropped by default: ARKit's 2 is "high".
DEFAULT_MIN_CONFIDENCE = 2


@dataclass(frozen=True)
class PhoneOptions:
    """Which frames of a phone export to write, which depth to trust, and camera overrides.

    ``camera`` (``--fx`` ...) is in the pixels of the photos as recorded, applied before any frame is
    resized or written.
    """

    every: int = 1
    max_frames: int | None = DEFAULT_MAX_FRAMES
    min_confidence: int = DEFAULT_MIN_CONFIDENCE
    camera: CameraFile = field(default_factory=CameraFile)

    def kept(self, numbers: Sequence[int]) -> list[int]:
        """Every ``every``-th frame number, at most ``max_frames`` of them evenly spread."""
        return spread(list(numbers)[:: max(1, self.every)], self.max_frames)

    def note(self, total: int, kept: int) -> str:
        """What was kept of a recording of ``total`` frames, and why."""
        return kept_note(total, kept, self.every, self.max_frames)
