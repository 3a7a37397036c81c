"""Build a reader from a config ``DataSource``: the one place formats are dispatched."""

from __future__ import annotations

from trainer.config import DataSource
from trainer.data.folders import FoldersReader
from trainer.data.frames import Frame, FrameReader
from trainer.data.manifest import ManifestReader
from trainer.data.nyu import NyuReader
from trainer.data.sevenscenes import SevenScenesReader
from trainer.data.tum import TumReader
from trainer.registration import ColourCamera, register_frame


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
    if source.format == "7scenes":
        reader = SevenScenesReader(source.root, source.frames)
    elif source.format == "tum":
        reader = TumReader(source.root)
    elif source.format == "nyu":
        reader = NyuReader(source.root, source.split, source.splits_file)
    elif source.format == "folders":
        reader = FoldersReader(source.root, source.frames, source.camera)
    else:
        reader = ManifestReader(source.root)
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
