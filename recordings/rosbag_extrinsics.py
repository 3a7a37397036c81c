"""Where a bag's depth camera sits relative to its colour camera, from what the bag itself stores.

A RealSense Viewer recording stores each stream's extrinsics from the device's reference
stream (``/device_0/sensor_N/<stream>/tf/0``: the reference frame's points mapped into the
stream's, as librealsense's ``get_extrinsics`` gives them). Other recordings carry
``/tf_static``, a tree of frames, in which the depth and colour images' ``frame_id`` are
joined through their parents.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

TF_STATIC = "tf2_msgs/msg/TFMessage"
#: A topic's deserialised messages, in time order.
Messages = Callable[[str], Iterable[Any]]


def depth_to_colour_extrinsics(
    messages: Messages,
    topics: list[tuple[str, str]],
    depth_topic: str,
    colour_topic: str,
    depth_frame: str,
    colour_frame: str,
) -> tuple[tuple[np.ndarray, np.ndarray], str]:
    """(rotation, translation) from the depth camera into the colour camera, and how they were found.

    ``messages(topic)`` gives a topic's messages; ``topics`` lists the bag's topics with their types.
    """
    realsense = [_realsense_tf(messages, topic) for topic in (depth_topic, colour_topic)]
    if all(t is not None for t in realsense):
        (r_d, t_d), (r_c, t_c) = realsense  # each maps the reference stream's frame into the stream's
        rotation = r_c @ r_d.T
        translation = t_c - rotation @ t_d
        source = "the RealSense recording's extrinsics"
    else:
        found = _tf_static(messages, topics, depth_frame, colour_frame)
        if found is None:
            return (np.eye(3), np.zeros(3)), (
                "depth moved into the colour camera by the two cameras' intrinsics only (the bag stores no "
                "extrinsics between them: record /tf_static, or depth aligned to colour)"
            )
        rotation, translation = found
        source = "/tf_static"
    angle = np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1, 1)))
    how = (
        f"depth moved into the colour camera with {source} (translation {np.linalg.norm(translation) * 1000:.1f} mm, "
        f"rotation {angle:.2f} deg)"
    )
    return (rotation, translation), how


def _rotation(q: Any) -> np.ndarray:
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _realsense_tf(messages: Messages, image_topic: str) -> tuple[np.ndarray, np.ndarray] | None:
    """A RealSense Viewer stream's ``tf/0``: the reference stream's frame mapped into this stream's."""
    if "/image/data" not in image_topic:
        return None
    topic = image_topic.replace("/image/data", "/tf/0")
    for message in messages(topic):
        t = message.translation
        return _rotation(message.rotation), np.array([t.x, t.y, t.z])
    return None


def _tf_static(
    messages: Messages, topics: list[tuple[str, str]], depth_frame: str, colour_frame: str
) -> tuple[np.ndarray, np.ndarray] | None:
    """The transform taking depth-frame points into the colour frame through ``/tf_static``'s tree, if joined."""
    if not depth_frame or not colour_frame:
        return None
    edges: dict[str, list[tuple[str, np.ndarray]]] = {}
    for topic in {topic for topic, msgtype in topics if msgtype == TF_STATIC}:
        for message in messages(topic):
            for stamped in message.transforms:
                t = stamped.transform.translation
                pose = np.eye(4)  # child's points into the parent's frame
                pose[:3, :3], pose[:3, 3] = _rotation(stamped.transform.rotation), [t.x, t.y, t.z]
                parent, child = stamped.header.frame_id.strip("/"), stamped.child_frame_id.strip("/")
                edges.setdefault(child, []).append((parent, pose))
                edges.setdefault(parent, []).append((child, np.linalg.inv(pose)))
    # Breadth-first from the depth frame: into_frame[f] maps depth-frame points into frame f.
    start, goal = depth_frame.strip("/"), colour_frame.strip("/")
    into_frame, queue = {start: np.eye(4)}, [start]
    while queue:
        frame = queue.pop(0)
        for neighbour, pose in edges.get(frame, []):
            if neighbour not in into_frame:
                into_frame[neighbour] = pose @ into_frame[frame]
                queue.append(neighbour)
    if goal not in into_frame:
        return None
    return into_frame[goal][:3, :3], into_frame[goal][:3, 3]
