"""Recordings in the formats users bring, written with each format's own library, for tests and benchmarks.

``BagWriter`` writes ROS 1 bags and ROS 2 bags (sqlite3 or MCAP) with ``rosbags``' writers;
``write_aligned_bag`` lays frames out as the RealSense ROS wrapper records them;
``write_stray_scanner`` writes a Stray Scanner export, its video encoded with PyAV;
``write_record3d`` writes a Record3D ``.r3d``, its depth compressed with LZFSE.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

from contract.geometry import Intrinsics

#: ../shared/data/mosd-tabletop's camera (its intrinsics.json).
MOSD_CAMERA = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)


class BagWriter:
    """Writes image, CameraInfo and tf messages into a ROS 1 bag or a ROS 2 bag (sqlite3 or MCAP)."""

    def __init__(self, path: Path, kind: str):
        self.ros1 = kind == "ros1"
        self.store = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if self.ros1:
            self.writer = Ros1Writer(path)
        else:
            plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
            self.writer = Ros2Writer(path, version=8, storage_plugin=plugin)
        self.connections: dict[str, object] = {}

    def __enter__(self) -> BagWriter:
        self.writer.open()
        return self

    def __exit__(self, *_) -> None:
        self.writer.close()

    def _header(self, t: float, frame: str):
        types = self.store.types
        stamp = types["builtin_interfaces/msg/Time"](sec=int(t), nanosec=round((t - int(t)) * 1e9))
        extra = {"seq": 0} if self.ros1 else {}
        return types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **extra)

    def write(self, topic: str, msgtype: str, t: float, message: object) -> None:
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        data = self.store.serialize_ros1(message, msgtype) if self.ros1 else self.store.serialize_cdr(message, msgtype)
        self.writer.write(self.connections[topic], int(t * 1e9), data)

    def image(self, topic: str, t: float, array: np.ndarray, encoding: str, frame: str = "camera") -> None:
        raw = np.ascontiguousarray(array)
        message = self.store.types["sensor_msgs/msg/Image"](
            header=self._header(t, frame),
            height=raw.shape[0],
            width=raw.shape[1],
            encoding=encoding,
            is_bigendian=0,
            step=raw.shape[1] * raw.itemsize * (raw.shape[2] if raw.ndim == 3 else 1),
            data=raw.view(np.uint8).ravel(),
        )
        self.write(topic, "sensor_msgs/msg/Image", t, message)

    def jpeg(self, topic: str, t: float, rgb: np.ndarray) -> bytes:
        buffer = io.BytesIO()
        Image.fromarray(rgb).save(buffer, format="JPEG", quality=95)
        message = self.store.types["sensor_msgs/msg/CompressedImage"](
            header=self._header(t, "camera"), format="jpeg", data=np.frombuffer(buffer.getvalue(), np.uint8)
        )
        self.write(topic, "sensor_msgs/msg/CompressedImage", t, message)
        return buffer.getvalue()

    def camera_info(
        self,
        topic: str,
        t: float,
        k: Intrinsics,
        frame: str = "camera",
        *,
        distortion: tuple[str, tuple[float, ...]] = ("plumb_bob", (0.0,) * 5),
        size: tuple[int, int] | None = None,
        uncalibrated: bool = False,
        rectified: Intrinsics | None = None,
    ) -> None:
        """A CameraInfo for ``k``: ``distortion`` (model, D), another ``size`` than ``k``'s, or K (and P) all zeros.

        P, the rectified images' camera, is ``rectified`` (at ``k``'s size), else ``k`` itself, as drivers write it.
        """
        types = self.store.types
        scale = 0.0 if uncalibrated else 1.0
        matrix = np.array([k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1], np.float64) * scale
        p = rectified or k
        projection = np.array([p.fx, 0, p.cx, 0, 0, p.fy, p.cy, 0, 0, 0, 1, 0], np.float64) * scale
        roi = types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        model, coefficients = distortion
        fields = {"D": np.asarray(coefficients, np.float64), "K": matrix, "R": np.eye(3).ravel(), "P": projection}
        if not self.ros1:
            fields = {key.lower(): value for key, value in fields.items()}
        width, height = size or (k.width, k.height)
        message = types["sensor_msgs/msg/CameraInfo"](
            header=self._header(t, frame),
            height=height,
            width=width,
            distortion_model=model,
            binning_x=0,
            binning_y=0,
            roi=roi,
            **fields,
        )
        self.write(topic, "sensor_msgs/msg/CameraInfo", t, message)

    def compressed_depth(self, topic: str, t: float, metres: np.ndarray, encoding: str) -> None:
        """Depth as image_transport's compressedDepth plugin publishes it: a 12-byte ``ConfigHeader``, then a PNG.

        ``16UC1``: the PNG holds millimetres. ``32FC1``: it holds quantised inverse depth with the plugin's
        defaults (depth_quantization 100, depth_max 10 m): A = 100 x 101, B = 1 - A / 10, v = A / d + B.
        """
        import struct

        if encoding == "16UC1":
            values, a, b = np.clip(np.rint(metres * 1000), 0, 65535).astype(np.uint16), 0.0, 0.0
        else:
            a = 100.0 * 101.0
            b = 1.0 - a / 10.0
            with np.errstate(divide="ignore"):
                inverse = np.where(metres > 0, a / np.maximum(metres, 1e-6) + b, 0.0)
            values = np.clip(np.rint(inverse), 0, 65535).astype(np.uint16)
        png = io.BytesIO()
        Image.fromarray(values).save(png, format="PNG")
        data = struct.pack("<iff", 0, a, b) + png.getvalue()
        message = self.store.types["sensor_msgs/msg/CompressedImage"](
            header=self._header(t, "camera"),
            format=f"{encoding}; compressedDepth png",
            data=np.frombuffer(data, np.uint8),
        )
        self.write(topic, "sensor_msgs/msg/CompressedImage", t, message)

    def tf_static(self, t: float, parent: str, child: str, translation: tuple[float, float, float]) -> None:
        types = self.store.types
        transform = types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](x=translation[0], y=translation[1], z=translation[2]),
            rotation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )
        stamped = types["geometry_msgs/msg/TransformStamped"](
            header=self._header(t, parent), child_frame_id=child, transform=transform
        )
        self.write("/tf_static", "tf2_msgs/msg/TFMessage", t, types["tf2_msgs/msg/TFMessage"](transforms=[stamped]))


def write_aligned_bag(
    path: Path,
    kind: str,
    frames,
    colour: str = "rgb8",
    depth: str = "16UC1",
    info: Intrinsics | None = None,
    start: float = 100.0,
    frame: str = "camera",
) -> Path:
    """A realsense-ros style recording: colour, depth aligned to colour, a CameraInfo each; 30 fps, 3 ms apart,
    from ``start`` seconds, in the colour camera's ``frame`` (a ROS 1 style "/camera" is possible too).

    The CameraInfo is mOSD's camera at the frames' size, or ``info`` (a driver's camera of another size).
    """
    k = info or MOSD_CAMERA.resized(frames[0][0].shape[1], frames[0][0].shape[0])
    with BagWriter(path, kind) as bag:
        for i, (rgb, mm) in enumerate(frames):
            t = start + i / 30
            if colour == "jpeg":
                bag.jpeg("/camera/color/image_raw/compressed", t, rgb)
            else:
                bag.image("/camera/color/image_raw", t, rgb[..., ::-1] if colour == "bgr8" else rgb, colour, frame)
            bag.camera_info("/camera/color/camera_info", t, k, frame)
            values = mm.astype(np.float32) / 1000.0 if depth == "32FC1" else mm
            bag.image("/camera/aligned_depth_to_color/image_raw", t + 0.003, values, depth, frame)
            bag.camera_info("/camera/aligned_depth_to_color/camera_info", t + 0.003, k, frame)
            bag.image("/camera/infra1/image_rect_raw", t, rgb[..., 0], "mono8")  # an infrared stream beside them
    return path


#: Stray Scanner's depth maps, whatever the video's size.
STRAY_DEPTH_SIZE = (256, 192)


def write_stray_scanner(
    root: Path, frames, camera: Intrinsics, odometry_frame_column: bool = True, fps: int = 30
) -> Path:
    """``frames`` ((rgb, depth mm) pairs) as a Stray Scanner export: rgb.mp4, 256x192 depth and confidence maps,
    camera_matrix.csv and odometry.csv (with the ``frame`` column the app writes now, or without, as it once did).

    Confidence is 2 where there is depth, 0 where there is none, and 1 over the top-left quarter.
    """
    import av

    (root / "depth").mkdir(parents=True)
    (root / "confidence").mkdir()
    height, width = frames[0][0].shape[:2]
    with av.open(str(root / "rgb.mp4"), "w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": "12"}
        for rgb, _ in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    for i, (_, depth) in enumerate(frames):
        small = np.asarray(Image.fromarray(depth).resize(STRAY_DEPTH_SIZE, Image.NEAREST), dtype=np.uint16)
        confidence = np.where(small > 0, 2, 0).astype(np.uint8)
        confidence[: small.shape[0] // 4, : small.shape[1] // 4] = 1
        Image.fromarray(small).save(root / "depth" / f"{i:06d}.png")
        Image.fromarray(confidence).save(root / "confidence" / f"{i:06d}.png")
    k = camera
    (root / "camera_matrix.csv").write_text(f"{k.fx},0.0,{k.cx}\n0.0,{k.fy},{k.cy}\n0.0,0.0,1.0\n")
    frame = ["frame"] if odometry_frame_column else []
    header = ", ".join(["timestamp", *frame, "x", "y", "z", "qx", "qy", "qz", "qw"])
    rows = [
        ", ".join([f"{100 + i / fps:.6f}", *([f"{i:06d}"] if frame else []), "0", "0", "0", "0", "0", "0", "1"])
        for i in range(len(frames))
    ]
    (root / "odometry.csv").write_text("\n".join([header, *rows]) + "\n")
    return root


def write_record3d(
    path: Path, frames, camera: Intrinsics, depth_size: tuple[int, int] = (256, 192), fps: int = 30
) -> Path:
    """``frames`` ((rgb, depth mm) pairs) as a Record3D ``.r3d``: metadata, rgbd/N.jpg, LZFSE .depth and .conf."""
    import json
    import zipfile

    import lzfse

    k = camera
    height, width = frames[0][0].shape[:2]
    metadata = {"K": [k.fx, 0, 0, 0, k.fy, 0, k.cx, k.cy, 1], "w": width, "h": height}
    metadata |= {"dw": depth_size[0], "dh": depth_size[1], "fps": fps}
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("metadata", json.dumps(metadata))
        for i, (rgb, depth) in enumerate(frames):
            buffer = io.BytesIO()
            Image.fromarray(rgb).save(buffer, format="JPEG", quality=95)
            archive.writestr(f"rgbd/{i}.jpg", buffer.getvalue())
            small = np.asarray(Image.fromarray(depth).resize(depth_size, Image.NEAREST), dtype=np.float32) / 1000.0
            archive.writestr(f"rgbd/{i}.depth", lzfse.compress(small.astype(np.float32).tobytes()))
            archive.writestr(f"rgbd/{i}.conf", lzfse.compress(np.where(small > 0, 2, 0).astype(np.uint8).tobytes()))
    return path
