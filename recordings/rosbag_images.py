"""Image messages of a ROS bag as arrays: colour (raw or compressed), depth (raw or compressedDepth).

``sensor_msgs/Image`` encodings per REP 118 (``16UC1``/``mono16`` raw units, ``32FC1`` metres), and
``CompressedImage`` as image_transport writes it: JPEG or PNG colour, and the compressedDepth plugin's
header-plus-PNG depth. Anything a damaged message's bytes raise while decoding is one of ``FRAME_DAMAGE``,
so the reader can skip and name that frame.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from PIL import Image

from contract.errors import UserError
from recordings.frames import PNG_MAGIC

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
COLOUR_ENCODINGS = {"rgb8": (3, False), "bgr8": (3, True), "rgba8": (4, False), "bgra8": (4, True), "mono8": (1, False)}
DEPTH_ENCODINGS = {"16UC1": np.uint16, "mono16": np.uint16, "32FC1": np.float32}


@dataclass(frozen=True)
class Stream:
    """One image topic: its type, frame count, first message's encoding and size."""

    topic: str
    msgtype: str
    count: int
    encoding: str
    width: int
    height: int

    @property
    def image(self) -> tuple[str, int, int]:
        """The topic and its images' width and height."""
        return self.topic, self.width, self.height

    @property
    def is_depth(self) -> bool:
        return self.encoding in DEPTH_ENCODINGS or "compresseddepth" in self.encoding.lower()

    @property
    def is_colour(self) -> bool:
        if self.msgtype == COMPRESSED:
            return not self.is_depth and "depth" not in self.topic.lower()
        return self.encoding in COLOUR_ENCODINGS and not any(w in self.topic.lower() for w in ("infra", "/ir"))


def message_size(message: Any, msgtype: str) -> tuple[int, int]:
    """(width, height) of an image message; a compressed one's from its image header (0, 0 if unreadable)."""
    if msgtype == IMAGE:
        return int(message.width), int(message.height)
    data = bytes(message.data)
    start = data.find(PNG_MAGIC) if "compresseddepth" in message.format.lower() else 0
    try:
        with Image.open(io.BytesIO(data[max(start, 0) :])) as im:
            return im.size
    except (OSError, ValueError):
        return 0, 0


def colour_image(message: Any, msgtype: str) -> bytes | np.ndarray:
    """A compressed frame's bytes as stored (JPEG or PNG), or a raw frame as HxWx3 uint8 RGB."""
    if msgtype == COMPRESSED:
        return bytes(message.data)
    channels, bgr = COLOUR_ENCODINGS[message.encoding]
    rows = np.frombuffer(bytes(message.data), np.uint8).reshape(message.height, message.step)
    pixels = rows[:, : message.width * channels].reshape(message.height, message.width, channels)
    if channels == 1:
        return np.repeat(pixels, 3, axis=2)
    rgb = pixels[..., :3]
    return np.ascontiguousarray(rgb[..., ::-1] if bgr else rgb)


def decoded(image: bytes | np.ndarray) -> np.ndarray:
    """``colour_image``'s result as HxWx3 uint8 RGB (a compressed frame decoded)."""
    if isinstance(image, np.ndarray):
        return image
    with Image.open(io.BytesIO(image)) as im:
        return np.asarray(im.convert("RGB"))


def compressed_depth(message: Any, units_m: float) -> np.ndarray:
    """image_transport's compressedDepth as metres: a 12-byte header, then a 16-bit PNG.

    The header (``compressed_depth_image_transport``'s ``ConfigHeader``) is the compression format
    (int32) and two float32 quantisation parameters A and B. ``16UC1`` PNGs hold the raw depth;
    ``32FC1`` PNGs hold quantised inverse depth, ``v = A / depth + B``, so ``depth = A / (v - B)``,
    and 0 is no reading.
    """
    data = bytes(message.data)
    start = data.find(PNG_MAGIC)
    if start < 0 or "rvl" in message.format.lower():
        raise UserError(f"compressed depth format {message.format!r} is not PNG; record raw or compressedDepth png")
    with Image.open(io.BytesIO(data[start:])) as im:
        values = np.asarray(im, dtype=np.float64)
    if "32FC1" not in message.format:
        return (values * units_m).astype(np.float32)
    if start < 12:
        raise UserError(f"compressed depth {message.format!r} has no quantisation header before its PNG")
    a, b = struct.unpack("<ff", data[start - 8 : start])
    with np.errstate(divide="ignore"):
        depth = np.where(values > 0, a / (values - b), 0.0)
    depth[~np.isfinite(depth) | (depth < 0)] = 0.0
    return depth.astype(np.float32)


def depth_image(message: Any, msgtype: str, units_m: float) -> np.ndarray:
    """A depth frame in metres, float32 (0 where there is no reading)."""
    if msgtype == COMPRESSED:
        return compressed_depth(message, units_m)
    dtype = np.dtype(DEPTH_ENCODINGS[message.encoding]).newbyteorder(">" if message.is_bigendian else "<")
    rows = np.frombuffer(bytes(message.data), np.uint8).reshape(message.height, message.step)
    values = rows[:, : message.width * dtype.itemsize].copy().view(dtype).reshape(message.height, message.width)
    depth = values.astype(np.float32) * units_m
    depth[~np.isfinite(depth)] = 0
    return depth


#: What a damaged frame's bytes raise when decoded: its pair is skipped and named, and the rest go on.
FRAME_DAMAGE = (OSError, ValueError, SyntaxError, struct.error, UserError)


def frame_damage(error: BaseException) -> str:
    """What is wrong with a frame that raised one of ``FRAME_DAMAGE``, in words: "damaged: ..."."""
    if isinstance(error, UserError):
        return f"damaged: {error}"
    if isinstance(error, struct.error) or "truncated" in str(error):
        return "damaged: cut short"
    if isinstance(error, OSError | SyntaxError):  # PIL's UnidentifiedImageError is an OSError
        return "damaged: not a readable JPEG or PNG"
    return "damaged: it holds fewer or other bytes than its size and encoding say"
