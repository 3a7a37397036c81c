"""Azure Kinect recordings as ``k4arecorder`` lays them out, written with PyAV (FFmpeg's Matroska muxer).

No Azure Kinect is attached here, so tests and benchmarks write the layout that Microsoft's "record file
format" document gives: a ``COLOR`` track (MJPEG, or raw NV12, YUY2 or BGRA) tagged ``K4A_COLOR_MODE``, a
``DEPTH`` track of big-endian 16-bit millimetres tagged ``K4A_DEPTH_MODE``, optionally an ``IR`` track, the
``K4A_DEPTH_DELAY_NS`` container tag, and the factory calibration attached as ``calibration.json``.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

#: How each colour format is stored: (FFmpeg codec, its pixel format, the FourCC of a raw one).
COLOUR_CODECS = {
    "MJPG": ("mjpeg", "yuvj422p", None),
    "NV12": ("rawvideo", "nv12", "NV12"),
    "YUY2": ("rawvideo", "yuyv422", "YUY2"),
    "BGRA": ("rawvideo", "bgra", "BGRA"),
}


def write_kinect_recording(
    path: Path,
    photos: Sequence[np.ndarray],
    depths_mm: Sequence[np.ndarray],
    colour_mode: str,
    depth_mode: str,
    calibration: bytes | None,
    depth_delay_ns: int = 0,
    fps: float = 30.0,
    ir: bool = True,
) -> Path:
    """Write RGB ``photos`` and uint16 ``depths_mm`` (one per frame, depth stamped ``depth_delay_ns`` later).

    ``colour_mode`` is the ``K4A_COLOR_MODE`` tag (``MJPG_720P``), ``depth_mode`` the ``K4A_DEPTH_MODE`` tag;
    ``calibration`` None leaves the attachment out, as a broken recording would.
    """
    codec, pixel_format, fourcc = COLOUR_CODECS[colour_mode.partition("_")[0]]
    step_ms = 1000 / fps
    # Raw video goes in as k4arecorder stores it, V_MS/VFW/FOURCC with the pixel format's FourCC (b16g for depth).
    with av.open(str(path), "w", format="matroska", options={"allow_raw_vfw": "1"}) as container:
        container.metadata["title"] = "Azure Kinect"
        container.metadata["K4A_DEPTH_DELAY_NS"] = str(depth_delay_ns)
        colour_tags = {"K4A_COLOR_MODE": colour_mode}
        colour = _track(container, codec, pixel_format, fourcc, photos[0].shape, "COLOR", colour_tags)
        depth_tags = {"K4A_DEPTH_MODE": depth_mode}
        depth = _track(container, "rawvideo", "gray16be", "b16g", depths_mm[0].shape, "DEPTH", depth_tags)
        ir_tags = {"K4A_IR_MODE": "ACTIVE"}
        infrared = _track(container, "rawvideo", "gray16be", "b16g", depths_mm[0].shape, "IR", ir_tags)
        if calibration is not None:
            container.add_attachment("calibration.json", "application/octet-stream", calibration)
        for i, (photo, depth_mm) in enumerate(zip(photos, depths_mm, strict=True)):
            t_ms = 200 + round(i * step_ms)
            _write(container, colour, av.VideoFrame.from_ndarray(np.ascontiguousarray(photo), format="rgb24"), t_ms)
            grey = av.VideoFrame.from_ndarray(np.ascontiguousarray(depth_mm.astype(np.uint16)), format="gray16le")
            _write(container, depth, grey, t_ms + round(depth_delay_ns / 1e6))
            if ir:
                _write(container, infrared, grey, t_ms + round(depth_delay_ns / 1e6))
        for stream in (colour, depth, infrared):
            for packet in stream.encode():
                container.mux(packet)
        raw = [(s, tag) for s, tag in ((colour, fourcc), (depth, "b16g"), (infrared, "b16g")) if tag]
        headers = [(s.width, s.height, tag) for s, tag in raw]
    _set_fourccs(Path(path), headers)
    return Path(path)


def _set_fourccs(path: Path, headers: list[tuple[int, int, str]]) -> None:
    """Write each raw track's FourCC into its BITMAPINFOHEADER's biCompression, as k4arecorder stores it.

    FFmpeg's Matroska muxer stores raw video in VFW mode as BI_RGB (biCompression 0), which reads back as RGB
    of that bit depth; the FourCC (b16g: big-endian 16-bit grey) is what says how to read the pixels.
    """
    data = bytearray(path.read_bytes())
    for width, height, fourcc in headers:
        for header in (struct.pack("<IiiH", 40, width, h, 1) for h in (height, -height)):  # top-down or bottom-up
            at = data.find(header)
            while at >= 0:
                compression = at + len(header) + 2  # after biBitCount
                data[compression : compression + 4] = fourcc.encode("ascii")
                at = data.find(header, at + 1)
    path.write_bytes(bytes(data))


def _track(
    container: av.container.OutputContainer,
    codec: str,
    pixel_format: str,
    fourcc: str | None,
    shape: tuple[int, ...],
    title: str,
    tags: dict[str, str],
) -> av.VideoStream:
    stream = container.add_stream(codec)
    stream.width, stream.height = shape[1], shape[0]
    stream.pix_fmt = pixel_format
    stream.time_base = stream.codec_context.time_base = Fraction(1, 1000)  # Matroska's own 1 ms timestamp scale
    stream.metadata.update({"title": title, **tags})
    return stream


def _write(container: av.container.OutputContainer, stream: av.VideoStream, frame: av.VideoFrame, t_ms: int) -> None:
    frame = frame.reformat(format=stream.pix_fmt)
    frame.pts = t_ms
    frame.time_base = stream.time_base
    for packet in stream.encode(frame):
        container.mux(packet)
