"""Served depth as the ROS 2 messages a depth camera's driver publishes, serialised as CDR (``rosbags``):
what the bag and the Foxglove sinks send, byte for byte the same.

Per frame, stamped with the source frame's time and in its colour frame:

- ``sensor_msgs/msg/Image``, 32FC1 depth in metres (REP 118), NaN where there is no depth;
- ``sensor_msgs/msg/CameraInfo`` of the camera the depth was inferred with (no distortion: the
  service's depth is of an ideal pinhole camera, P = [K | 0]);
- ``sensor_msgs/msg/PointCloud2``, float32 x, y, z and the packed ``rgb`` RViz colours by, one point
  per valid pixel (``is_dense``);
- optionally the colour photo (``CompressedImage``, as sent) and the sensor's own depth (32FC1);
- once, with a parent frame named, ``tf2_msgs/msg/TFMessage`` on ``/tf_static``: the optical frame at the
  parent's origin, turned as REP 103 turns an optical frame (z forward, x right, y down) against a body frame
  (x forward, y left, z up), as realsense-ros places ``camera_color_optical_frame`` under ``camera_color_frame``.

Topic names follow realsense-ros under a namespace of our own (``/rgb2cloud`` by default), so a bag played
(or a live view run) beside the real sensor's driver never publishes on its ``/camera`` topics. Every image
topic has its CameraInfo beside it. Frame ids are tf2's: no leading slash (ROS 1 bags often carry one, which
tf2 refuses).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from clients.sinks import DecodedFrame
from contract.errors import UserError
from contract.geometry import Intrinsics

#: PointCloud2 field datatype FLOAT32 (sensor_msgs/msg/PointField).
FLOAT32 = 7
#: Bytes per point: x, y, z and rgb, four float32s.
POINT_STEP = 16
#: The rotation (x, y, z, w) from a REP 103 body frame to its optical frame: z forward, x right, y down.
OPTICAL_ROTATION = (-0.5, 0.5, -0.5, 0.5)
#: Where tf2's static transforms go: a topic of its own, outside any namespace.
TF_STATIC = "/tf_static"
IMAGE, CAMERA_INFO, CLOUD = "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo", "sensor_msgs/msg/PointCloud2"
COMPRESSED, TF_MESSAGE = "sensor_msgs/msg/CompressedImage", "tf2_msgs/msg/TFMessage"


#: Each message's topic under the namespace, as realsense-ros names its own.
TOPICS = {
    "depth": "aligned_depth_to_color/image_raw",
    "depth_info": "aligned_depth_to_color/camera_info",
    "points": "depth/color/points",
    "colour": "color/image_raw/compressed",
    "colour_info": "color/camera_info",
    "sensor_depth": "sensor/aligned_depth_to_color/image_raw",
    "sensor_depth_info": "sensor/aligned_depth_to_color/camera_info",
}


@dataclass(frozen=True)
class Topics:
    """Where each message goes: ``TOPICS`` under ``namespace`` (``/camera/aligned_depth_to_color/image_raw``)."""

    namespace: str = "/rgb2cloud"

    def __post_init__(self) -> None:
        if not self.namespace.startswith("/") or self.namespace.endswith("/"):
            raise UserError(f"--namespace {self.namespace!r}: a ROS name starts with / and does not end with one")

    def __getitem__(self, kind: str) -> str:
        return f"{self.namespace}/{TOPICS[kind]}"


def point_records(xyz: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """N points as PointCloud2 data, 16 bytes each: x, y, z as float32, then the colour as PCL packs it,
    0x00RRGGBB in a little-endian uint32 (bytes b, g, r, 0) read as the bits of a float32 ``rgb`` field.

    Written in place, column by column: a full-resolution cloud is 4.9 MB a frame, and every copy of it
    is time taken from the model on the same cores."""
    records = np.zeros((len(xyz), POINT_STEP), dtype=np.uint8)
    records.view("<f4")[:, :3] = xyz
    records[:, 12:15] = rgb[:, ::-1]
    return records


@dataclass(frozen=True)
class Message:
    """One serialised message: where it goes, its type (``sensor_msgs/msg/Image``), stamp and CDR bytes."""

    topic: str
    msgtype: str
    stamp_ns: int
    cdr: bytes


class RosMessages:
    """Each answer as its ROS 2 messages (humble's definitions, which Jazzy's and Kilted's match for these)."""

    def __init__(
        self,
        topics: Topics,
        frame_id: str,
        with_colour: bool = False,
        with_sensor_depth: bool = False,
        tf_parent: str | None = None,
    ):
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.topics, self.frame_id = topics, frame_id.lstrip("/")  # tf2 refuses a leading slash
        self.with_colour, self.with_sensor_depth = with_colour, with_sensor_depth
        self.tf_parent = None if tf_parent is None else tf_parent.lstrip("/")
        if self.tf_parent is not None and self.tf_parent in ("", self.frame_id):
            raise UserError(f"--tf-parent {tf_parent!r}: name a frame other than the depth's own ({self.frame_id})")

    def topic_types(self) -> list[tuple[str, str]]:
        """Every (topic, type) these messages go out on, for an output that announces its topics up front."""
        kinds = [("depth", IMAGE), ("depth_info", CAMERA_INFO), ("points", CLOUD)]
        if self.with_colour:
            kinds += [("colour", COMPRESSED), ("colour_info", CAMERA_INFO)]
        if self.with_sensor_depth:
            kinds += [("sensor_depth", IMAGE), ("sensor_depth_info", CAMERA_INFO)]
        found = [(self.topics[kind], msgtype) for kind, msgtype in kinds]
        return found + ([(TF_STATIC, TF_MESSAGE)] if self.tf_parent is not None else [])

    def static(self, stamp_ns: int) -> Message | None:
        """``/tf_static``'s one message, stamped ``stamp_ns``, if a parent frame was named: each sink sends it
        once, before its first frame."""
        if self.tf_parent is None:
            return None
        types = self.store.types
        header = self._header(stamp_ns)
        header.frame_id = self.tf_parent
        x, y, z, w = OPTICAL_ROTATION
        transform = types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            rotation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
        )
        stamped = types["geometry_msgs/msg/TransformStamped"](
            header=header, child_frame_id=self.frame_id, transform=transform
        )
        return self._message(TF_STATIC, TF_MESSAGE, stamp_ns, types[TF_MESSAGE]([stamped]))

    def definition(self, msgtype: str) -> str:
        """The type's ``ros2msg`` text, its dependencies after it (what MCAP and Foxglove take as its schema)."""
        return self.store.generate_msgdef(msgtype, ros_version=2)[0]

    def __call__(self, answer: DecodedFrame) -> Iterator[Message]:
        stamp, k, topics = answer.stamp_ns, answer.camera, self.topics
        yield self._message(topics["depth"], IMAGE, stamp, self._depth(stamp, answer.metres))
        yield self._message(topics["depth_info"], CAMERA_INFO, stamp, self._info(stamp, k))
        points = self._cloud(stamp, answer.xyz, answer.rgb)
        yield self._message(topics["points"], CLOUD, stamp, points)
        if self.with_colour:
            kind = "png" if answer.photo[:4] == b"\x89PNG" else "jpeg"
            photo = self.store.types[COMPRESSED](
                header=self._header(stamp), format=kind, data=np.frombuffer(answer.photo, np.uint8)
            )
            yield self._message(topics["colour"], COMPRESSED, stamp, photo)
            yield self._message(topics["colour_info"], CAMERA_INFO, stamp, self._info(stamp, k))
        if self.with_sensor_depth and answer.sensor_metres is not None:
            sensor = answer.sensor_metres
            yield self._message(topics["sensor_depth"], IMAGE, stamp, self._depth(stamp, sensor))
            info = self._info(stamp, k.resized(sensor.shape[1], sensor.shape[0]))
            yield self._message(topics["sensor_depth_info"], CAMERA_INFO, stamp, info)

    def _message(self, topic: str, msgtype: str, stamp_ns: int, message: Any) -> Message:
        return Message(topic, msgtype, stamp_ns, bytes(self.store.serialize_cdr(message, msgtype)))

    def _header(self, stamp_ns: int) -> Any:
        types = self.store.types
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        return types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=self.frame_id
        )

    def _depth(self, stamp_ns: int, metres: np.ndarray) -> Any:
        """32FC1 metres, NaN where there is no depth (0 in the service's millimetres)."""
        values = np.array(metres, dtype="<f4", order="C")  # a copy, row-major whatever the input's layout
        values[~(values > 0)] = np.nan
        height, width = values.shape
        return self.store.types[IMAGE](
            header=self._header(stamp_ns),
            height=height,
            width=width,
            encoding="32FC1",
            is_bigendian=0,
            step=width * 4,
            data=values.view(np.uint8).ravel(),
        )

    def _info(self, stamp_ns: int, k: Intrinsics) -> Any:
        return self.store.types[CAMERA_INFO](
            header=self._header(stamp_ns),
            height=k.height,
            width=k.width,
            distortion_model="plumb_bob",
            d=np.zeros(5),
            k=np.array([k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1], dtype=np.float64),
            r=np.eye(3).ravel(),
            p=np.array([k.fx, 0, k.cx, 0, 0, k.fy, k.cy, 0, 0, 0, 1, 0], dtype=np.float64),
            binning_x=0,
            binning_y=0,
            roi=self.store.types["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            ),
        )

    def _cloud(self, stamp_ns: int, xyz: np.ndarray, rgb: np.ndarray) -> Any:
        """One point per valid pixel: x, y, z in metres (camera frame) and the packed rgb, 16 bytes each."""
        types = self.store.types
        fields = [
            types["sensor_msgs/msg/PointField"](name=name, offset=4 * i, datatype=FLOAT32, count=1)
            for i, name in enumerate(("x", "y", "z", "rgb"))
        ]
        return types[CLOUD](
            header=self._header(stamp_ns),
            height=1,
            width=len(xyz),
            fields=fields,
            is_bigendian=False,
            point_step=POINT_STEP,
            row_step=POINT_STEP * len(xyz),
            data=point_records(xyz, rgb).ravel(),
            is_dense=True,
        )
