"""A training config's data sources as frames: the recordings' readers, as ``train`` and ``evaluate`` read them."""

from __future__ import annotations

from recordings.folders import CameraFile, select_frames
from recordings.formats import ReadOptions, open_pairs
from recordings.frames import Frame, FrameReader
from recordings.nyu import NyuReader
from recordings.registration import ColourCamera, register_frame
from recordings.sevenscenes import SevenScenesReader
from trainer.config import DataSource


class RegisteredReader:
    """A reader whose frames carry depth moved into a colour camera (``register_frame``)."""

    def __init__(self, reader: FrameReader, colour: ColourCamera):
        self.reader, self.colour = reader, colour
        self.name, self.licence = reader.name, reader.licence

    def __len__(self) -> int:
        return len(self.reader)

    def __getitem__(self, index: int) -> Frame:
        return register_frame(self.reader[index], self.colour)


def open_source(source: DataSource) -> FrameReader:
    """A config's data source as frames: ``open_pairs`` for every file layout, NYU's split as arrays."""
    if source.format == "nyu":
        reader: FrameReader = NyuReader(source.root, source.split, source.splits_file)
    elif source.format == "7scenes":
        reader = SevenScenesReader(source.root, source.frames)  # 7-Scenes selects by frame number
    else:
        pairs = open_pairs(source.root, source.format, ReadOptions(camera=source.camera or CameraFile()), None)
        reader = pairs.selected(select_frames([p.name for p in pairs.pairs], source.frames)) if source.frames else pairs
    if source.licence:
        reader.licence = source.licence
    if source.colour_camera:
        return RegisteredReader(reader, source.colour_camera)
    return reader


def describe(source: DataSource) -> str:
    """A short human label: '7scenes-redkitchen 850-999', 'nyu test', ..."""
    reader_name = source.root.name if source.format != "nyu" else "nyu-depth-v2"
    selection = source.frames or (source.split if source.format == "nyu" else "all")
    return f"{reader_name} {selection}"
