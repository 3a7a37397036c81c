"""``rgb2cloud stream --foxglove``: the live topics read by a client we did not write.

The client (``tests/foxglove_client/subscribe.mjs``) is Foxglove's own npm libraries: ``@foxglove/ws-protocol``
connects and subscribes, ``@foxglove/rosmsg`` parses each channel's ``ros2msg`` schema and
``@foxglove/rosmsg2-serialization`` decodes the CDR. Its depth, CameraInfo and PointCloud2 are checked against
``POST /depth`` and ``POST /pointcloud`` of the photo the colour topic carries: the one that was sent.
"""

from __future__ import annotations

import base64
import io
import json
import socket
import subprocess
import sys
import time

import httpx
import numpy as np
import pytest
from conftest import REPO
from plyfile import PlyData
from test_stream_cli import KITCHEN, posted_depth, service, write_video  # noqa: F401 - service is a fixture

from harness.service import free_port

pytestmark = pytest.mark.slow

CLIENT = REPO / "tests" / "foxglove_client"
NS = "/rgb2cloud"
TOPICS = {
    "depth": f"{NS}/aligned_depth_to_color/image_raw",
    "info": f"{NS}/aligned_depth_to_color/camera_info",
    "points": f"{NS}/depth/color/points",
    "colour": f"{NS}/color/image_raw/compressed",
    "tf": "/tf_static",
}


@pytest.fixture(scope="module")
def foxglove_client() -> list[str]:
    """The client's command; its packages installed from the lock file the first time (npm's registry)."""
    if not (CLIENT / "node_modules" / "@foxglove" / "ws-protocol").exists():
        subprocess.run(["npm", "ci", "--silent", "--no-audit", "--no-fund"], cwd=CLIENT, check=True, timeout=600)
    return ["node", str(CLIENT / "subscribe.mjs")]


def wait_listening(port: int, process: subprocess.Popen, timeout_s: float = 60) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert process.poll() is None, process.communicate()[1]
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise AssertionError(f"nothing listens on {port} after {timeout_s} s")


def decoded(entry: dict) -> bytes:
    return base64.b64decode(entry["base64"])


def test_foxglove_clients_see_depth_camera_info_and_clouds_that_are_the_services(service, foxglove_client, tmp_path):  # noqa: F811
    stamps = write_video(tmp_path / "kitchen.mp4", KITCHEN[:30])
    port = free_port()
    # 30 frames recorded over 1 s, played at a quarter of their pace: 4 s live, for the client to join. The first
    # /tf_static goes out as its channel is made, with the first frame, before any client can have subscribed to
    # it, so it reaches the client only as a latched topic reaches a late subscriber.
    live = ["--foxglove", f"127.0.0.1:{port}", "--rate", "0.25", "--with-colour", "--stride", "4"]
    live += ["--tf-parent", "camera_link"]
    cli = subprocess.Popen(
        [sys.executable, "-m", "cli", "stream", str(tmp_path / "kitchen.mp4"), "--url", service, *live],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_listening(port, cli)
        client = subprocess.run(
            [*foxglove_client, f"ws://127.0.0.1:{port}", "60", *TOPICS.values()],
            capture_output=True,
            text=True,
            timeout=90,
        )
        assert client.returncode == 0, client.stderr
        out, err = cli.communicate(timeout=120)
    finally:
        cli.kill()
    assert cli.returncode == 0 and "30 frames written" in out, err
    assert "Callback failed" not in err, err  # the server's listener handles a client leaving too
    got = {kind: json.loads(client.stdout)[topic] for kind, topic in TOPICS.items()}

    # ROS 2 messages as CDR with their ros2msg schemas, as foxglove_bridge advertises a ROS robot's.
    schemas = {
        "depth": "sensor_msgs/msg/Image",
        "info": "sensor_msgs/msg/CameraInfo",
        "points": "sensor_msgs/msg/PointCloud2",
        "colour": "sensor_msgs/msg/CompressedImage",
        "tf": "tf2_msgs/msg/TFMessage",
    }
    for kind, name in schemas.items():
        assert got[kind]["channel"] == {"encoding": "cdr", "schemaName": name, "schemaEncoding": "ros2msg"}
    depth, info, cloud, colour = (got[k]["message"] for k in ("depth", "info", "points", "colour"))
    stamp = depth["header"]["stamp"]
    assert stamp["sec"] * 1_000_000_000 + stamp["nanosec"] in stamps  # the video's own time
    assert {m["header"]["frame_id"] for m in (depth, info, cloud, colour)} == {"camera_color_optical_frame"}

    # The optical frame under the parent named, turned as REP 103 says (test_ros2 checks the rotation's meaning).
    (transform,) = got["tf"]["message"]["transforms"]
    assert (transform["header"]["frame_id"], transform["child_frame_id"]) == (
        "camera_link",
        "camera_color_optical_frame",
    )
    assert transform["transform"]["rotation"] == {"x": -0.5, "y": 0.5, "z": -0.5, "w": 0.5}

    # The depth is /depth's for the photo that was sent, to the millimetre, NaN where /depth has none.
    photo = decoded(colour["data"])
    assert colour["format"] == "jpeg"
    assert (depth["encoding"], depth["width"], depth["height"], depth["step"]) == ("32FC1", 640, 480, 2560)
    metres = np.frombuffer(decoded(depth["data"]), dtype="<f4").reshape(480, 640)
    served = posted_depth(service, photo)
    assert np.array_equal(np.isnan(metres), served == 0)
    np.testing.assert_array_equal(np.rint(np.nan_to_num(metres) * 1000), np.rint(served * 1000))

    # The camera the depth was inferred with: no focal length known, so the model's (fx = fy = 530).
    assert (info["width"], info["height"]) == (640, 480)
    assert info["k"] == pytest.approx([530.0, 0, info["k"][2], 0, 530.0, info["k"][5], 0, 0, 1])
    assert info["p"] == pytest.approx([530.0, 0, info["k"][2], 0, 0, 530.0, info["k"][5], 0, 0, 0, 1, 0])

    # The cloud is /pointcloud's points at the same stride, in its order, with the colours packed as PCL does.
    response = httpx.post(f"{service}/pointcloud", files={"image": photo}, params={"stride": 4}, timeout=60)
    ply = PlyData.read(io.BytesIO(response.content))["vertex"]
    records = np.frombuffer(decoded(cloud["data"]), dtype="<f4").reshape(-1, 4)
    assert cloud["width"] == ply.count == len(records) and cloud["point_step"] == 16
    assert [(f["name"], f["offset"], f["datatype"]) for f in cloud["fields"]] == [
        ("x", 0, 7),
        ("y", 4, 7),
        ("z", 8, 7),
        ("rgb", 12, 7),
    ]
    np.testing.assert_array_equal(records[:, :3], np.stack([ply["x"], ply["y"], ply["z"]], axis=1))
    packed = records[:, 3].copy().view("<u4")
    unpacked = np.stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255], axis=1)
    np.testing.assert_array_equal(unpacked, np.stack([ply["red"], ply["green"], ply["blue"]], axis=1))


def test_a_foxglove_address_that_is_not_one_is_one_line(service, tmp_path):  # noqa: F811
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.jpg").write_bytes(KITCHEN[0].read_bytes())
    for given in ("eighty", "127.0.0.1:99999"):
        result = subprocess.run(
            [sys.executable, "-m", "cli", "stream", str(tmp_path / "photos"), "--url", service, "--foxglove", given],
            cwd=REPO,
            capture_output=True,
            text=True,
        )
        assert result.returncode != 0 and "Traceback" not in result.stderr, result.stderr
        assert f"--foxglove {given!r}: give [HOST:]PORT" in result.stderr


def test_the_server_speaks_foxglove_sdk_v1_and_refuses_a_client_offering_only_websocket_v1():
    # What docs/robotics.md says of which apps connect: Lichtblick up to 1.21.0 offers foxglove.websocket.v1 alone.
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    from clients.sinks.foxglove import FoxgloveSink
    from clients.sinks.ros_messages import RosMessages, Topics

    sink = FoxgloveSink("127.0.0.1:0", RosMessages(Topics(), "camera_color_optical_frame"))
    try:
        with pytest.raises(InvalidStatus) as refused:
            connect(f"ws://127.0.0.1:{sink.port}", subprotocols=["foxglove.websocket.v1"], open_timeout=10)
        assert refused.value.response.status_code == 400
        with connect(f"ws://127.0.0.1:{sink.port}", subprotocols=["foxglove.sdk.v1"], open_timeout=10) as socket:
            assert socket.subprotocol == "foxglove.sdk.v1"
            assert json.loads(socket.recv(timeout=10))["op"] == "serverInfo"
    finally:
        sink.close()
