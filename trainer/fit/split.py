"""An honest split of one recording: train on the start, skip a gap, hold out the end.

Neighbouring video frames look almost alike, so scoring on frames interleaved with
training ones measures memory, not the place. The default is time order: the first
75% train, the next 5% are dropped, the last 20% are held out. Model selection uses
the end of the train part, never the held-out frames, which are scored once, at the
end. ``--holdout`` names the held-out frames instead: names, globs or index ranges.
"""

from __future__ import annotations

from dataclasses import dataclass

from contract.errors import UserError
from recordings.folders import select_frames
from recordings.frames import RecordedPair

TRAIN_SHARE, GAP_SHARE = 0.75, 0.05
#: The end of the train part that chooses the checkpoint.
SELECTION_SHARE = 0.1
#: Fewer pairs than this leave a split part too small to mean anything.
MIN_PAIRS = 20


@dataclass
class Split:
    """Indices into the recording's pairs (time order) for each part."""

    train: list[int]
    selection: list[int]
    gap: list[int]
    holdout: list[int]

    def summary(self, pairs: list[RecordedPair]) -> dict[str, object]:
        """What the card records: counts and the first and last name of each part."""

        def part(indices: list[int]) -> dict[str, object]:
            names = [pairs[i].name for i in indices]
            return {"frames": len(names), "first": names[0] if names else None, "last": names[-1] if names else None}

        return {name: part(getattr(self, name)) for name in ("train", "selection", "gap", "holdout")}

    def line(self) -> str:
        return (
            f"split: train {len(self.train)}, selection {len(self.selection)} (the end of the train part), "
            f"gap {len(self.gap)}, held out {len(self.holdout)}"
        )


def split_recording(pairs: list[RecordedPair], holdout: str | None = None, gap_frames: int | None = None) -> Split:
    """The default time-order split, or the one ``holdout`` names; raise UserError if too small."""
    n = len(pairs)
    if n < MIN_PAIRS:
        raise UserError(f"{n} usable pairs; fit needs at least {MIN_PAIRS} (record a little longer)")
    gap = round(GAP_SHARE * n) if gap_frames is None else gap_frames
    if holdout:
        try:
            held = select_frames([p.name for p in pairs], holdout)
        except ValueError as e:
            raise UserError(f"--holdout: {e}") from None
        near = {j for i in held for j in range(i - gap, i + gap + 1) if 0 <= j < n} - set(held)
        rest = [i for i in range(n) if i not in near and i not in set(held)]
        gap_indices = sorted(near)
    else:
        train_end = round(TRAIN_SHARE * n)
        held = list(range(min(train_end + gap, n - 1), n))
        rest = list(range(train_end))
        gap_indices = list(range(train_end, held[0]))
    selection_count = max(1, round(SELECTION_SHARE * len(rest)))
    split = Split(rest[:-selection_count], rest[-selection_count:], gap_indices, held)
    if len(split.train) < MIN_PAIRS // 2 or not split.holdout:
        raise UserError(
            f"{split.line()}: too few frames to train on or to score; fit needs at least {MIN_PAIRS // 2} train "
            f"frames and one held-out frame"
        )
    return split
