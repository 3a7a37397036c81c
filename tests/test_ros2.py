"""``rgb2cloud stream --ros2``: live ROS 2 topics over DDS, read by a subscriber we did not write.

The subscriber (``tests/dds_subscriber/``) is Debian's Eclipse Cyclone DDS C library, the 0.10 line that
rmw_cyclonedds uses, with types its ``idlc`` generates from IDL written by hand from the ROS ``.msg`` files. It
asks for what a ROS 2 subscription asks for and keeps each payload as it came off the wire. Those payloads must
decode, with rosbags, to the very messages ``--bag`` writes in the same run, field by field.

The discovery data is read from a capture of the traffic by Wireshark's RTPS dissector (``tshark``) and
checked against what real ROS 2 endpoints announce (``ROS2_EXPECTED``).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO
from PIL import Image
from rosbags.typesys import Stores, get_typestore
from test_stream_cli import KITCHEN, MOSD, read_bag, service, write_video  # noqa: F401 - service is a fixture

from harness.recordings import write_aligned_bag
from harness.ros2_subscriber import Subscription, build_subscriber, fresh_domain, loopback_env

pytestmark = pytest.mark.slow

NS = "/rgb2cloud"
DEPTH, INFO, POINTS = (
    f"{NS}/aligned_depth_to_color/image_raw",
    f"{NS}/aligned_depth_to_color/camera_info",
    f"{NS}/depth/color/points",
)
#: What ROS 2 endpoints announce, and where each value comes from (not from rgb2cloud's code):
#: - topic names: rmw's ``rt`` prefix for topics (rmw_dds_common, ``ros_topic_prefix``);
#: - type names: rosidl's ``<package>::msg::dds_::<Type>_`` as rmw_cyclonedds and rmw_fastrtps register them;
#: - reliability RELIABLE (2), durability VOLATILE (0): rmw's default QoS profile (``rmw_qos_profile_default``,
#:   KEEP_LAST 10); /tf_static TRANSIENT_LOCAL (1), tf2_ros's ``StaticBroadcasterQoS``;
#: - data representation XCDR1 (0): rmw_cyclonedds offers only XCDR1 for ROS types;
#: - ``typehash=RIHS01_<hash>;`` in USER_DATA (rmw_dds_common's ``encode_type_hash_for_user_data_qos``, Jazzy
#:   and later), the hash as rosbags' ``hash_rihs01`` gives it for Jazzy and Kilted: the same for these types.
ROS2_EXPECTED = {
    DEPTH: (
        "sensor_msgs::msg::dds_::Image_",
        "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    ),
    INFO: (
        "sensor_msgs::msg::dds_::CameraInfo_",
        "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275",
    ),
    POINTS: (
        "sensor_msgs::msg::dds_::PointCloud2_",
        "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
    ),
    "/tf_static": (
        "tf2_msgs::msg::dds_::TFMessage_",
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    ),
}
RELIABLE, VOLATILE, TRANSIENT_LOCAL, XCDR1 = 2, 0, 1, 0


@pytest.fixture(scope="module")
def subscriber(tmp_path_factory) -> Path:
    return build_subscriber(tmp_path_factory.mktemp("dds_subscriber"))


def stream(service_url: str, source: Path, domain: int, *options: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "cli", "stream", str(source), "--url", service_url, "--ros2", *options],
        cwd=REPO,
        env=loopback_env(domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def same(a, b, path: str = "") -> None:
    """Two decoded messages equal field by field (arrays element by element, NaN where NaN)."""
    if isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=path)
    elif hasattr(a, "__dataclass_fields__"):
        assert type(a).__name__ == type(b).__name__, path
        for name in a.__dataclass_fields__:
            if name != "__msgtype__":
                same(getattr(a, name), getattr(b, name), f"{path}.{name}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same(x, y, f"{path}[{i}]")
    else:
        assert a == b, (path, a, b)


def kitchen_folder(folder: Path, count: int) -> Path:
    folder.mkdir()
    for photo in KITCHEN[:count]:
        shutil.copy(photo, folder / photo.name)
    return folder


def mosd_bag(path: Path, count: int) -> Path:
    photos = sorted((MOSD / "color").glob("learn*.jpg"))[:count]
    frames = [
        (np.asarray(Image.open(p).convert("RGB")), np.asarray(Image.open(MOSD / "depth" / f"{p.stem}.png")))
        for p in photos
    ]
    return write_aligned_bag(path, "mcap", frames, start=1_764_000_000.123456789)


@pytest.mark.parametrize("kind", ["folder", "video", "ros2 bag"])
def test_a_ros2_subscriber_gets_the_messages_the_bag_gets(service, subscriber, tmp_path, kind):  # noqa: F811
    count = 4
    source = {
        "folder": lambda: kitchen_folder(tmp_path / "photos", count),
        "video": lambda: (write_video(tmp_path / "kitchen.mp4", KITCHEN[:count]), tmp_path / "kitchen.mp4")[1],
        "ros2 bag": lambda: mosd_bag(tmp_path / "recording", count),
    }[kind]()
    domain = fresh_domain()
    types = {DEPTH: "sensor_msgs/msg/Image", INFO: "sensor_msgs/msg/CameraInfo", POINTS: "sensor_msgs/msg/PointCloud2"}
    wanted = [f"{t}={m}:{count}" for t, m in types.items()]
    options = ["--bag", str(tmp_path / "bag"), "--stride", "2"]
    if kind == "ros2 bag":  # a recording also has its colour and its own depth to give, and a parent frame
        types |= {
            f"{NS}/color/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
            f"{NS}/color/camera_info": "sensor_msgs/msg/CameraInfo",
            f"{NS}/sensor/aligned_depth_to_color/image_raw": "sensor_msgs/msg/Image",
            f"{NS}/sensor/aligned_depth_to_color/camera_info": "sensor_msgs/msg/CameraInfo",
        }
        wanted = [f"{t}={m}:{count}" for t, m in types.items()]
        types["/tf_static"] = "tf2_msgs/msg/TFMessage"
        wanted.append("/tf_static=tf2_msgs/msg/TFMessage@transient_local:1")
        options += ["--with-colour", "--with-sensor-depth", "--tf-parent", "camera_link"]
    listening = Subscription(subscriber, domain, tmp_path / "got", wanted)
    streaming = stream(service, source, domain, *options)
    _, err = streaming.communicate(timeout=300)
    assert streaming.returncode == 0, err
    assert f"ROS 2: publishing under {NS} in domain {domain}" in err
    got = listening.received()
    bag = read_bag(tmp_path / "bag")
    store = get_typestore(Stores.ROS2_JAZZY)
    for (topic, msgtype), payloads in zip(types.items(), got, strict=True):
        written = bag[topic]
        assert len(payloads) == len(written) == (1 if topic == "/tf_static" else count), topic
        for payload, (bag_type, _, message) in zip(payloads, written, strict=True):
            assert payload[:2] == b"\x00\x01"  # the encapsulation: CDR, little-endian (XCDR1)
            assert bag_type == msgtype
            same(store.deserialize_cdr(payload, msgtype), message, topic)
    cloud = store.deserialize_cdr(got[2][0], "sensor_msgs/msg/PointCloud2")
    assert cloud.width > 1000 and cloud.point_step == 16  # a real cloud went through, not an empty one


def parameter_lists(tree) -> list[dict]:
    """Every RTPS parameter list in tshark's JSON (one per endpoint announced), wherever it sits."""
    if isinstance(tree, list):
        return [found for item in tree for found in parameter_lists(item)]
    if not isinstance(tree, dict):
        return []
    here = [tree] if "PID_TOPIC_NAME" in tree and "PID_ENDPOINT_GUID" in tree else []
    return here + [found for value in tree.values() for found in parameter_lists(value)]


def representations(parameter: dict | None) -> list[str] | None:
    """PID_DATA_REPRESENTATION's list (``["0"]`` for XCDR1 alone), None where it was not sent."""
    if parameter is None:
        return None
    (sequence,) = [value for key, value in parameter.items() if key.startswith("Data Representation Sequence")]
    found = sequence.get("rtps.param.data_representation", [])
    return found if isinstance(found, list) else [found]


def announced_writers(capture: Path) -> dict[str, dict]:
    """The writers announced in a capture (SEDP), as Wireshark's RTPS dissector reads them, by topic: each
    parameter as the dissector names it, None where it was not sent (the value is then the spec's default)."""
    command = ["tshark", "-r", str(capture), "-Y", "rtps.param.topicName", "-T", "json", "--no-duplicate-keys"]
    dissected = subprocess.run(command, capture_output=True, text=True)
    assert dissected.returncode == 0, dissected.stderr
    writers: dict[str, dict] = {}
    for parameters in parameter_lists(json.loads(dissected.stdout)):
        guid = parameters["PID_ENDPOINT_GUID"]["rtps.param.endpoint_guid_tree"]
        if int(guid["rtps.param.guid.entityId_tree"]["rtps.param.guid.entityKind"], 0) not in (0x02, 0x03):
            continue  # a reader (the subscriber's), not a writer
        writers[parameters["PID_TOPIC_NAME"]["rtps.param.topicName"]] = {
            "type": parameters["PID_TYPE_NAME"]["rtps.param.typeName"],
            "reliability": parameters.get("PID_RELIABILITY", {}).get("rtps.reliability_kind"),
            "durability": parameters.get("PID_DURABILITY", {}).get("rtps.durability"),
            "representation": representations(parameters.get("PID_DATA_REPRESENTATION")),
            "user_data": parameters.get("PID_USER_DATA", {}).get("rtps.param.userData"),
        }
    return writers


def test_discovery_says_what_ros2_endpoints_say_and_a_late_node_gets_tf_static(service, subscriber, tmp_path):  # noqa: F811
    if os.geteuid() != 0:
        pytest.skip("capturing the loopback interface needs root")
    write_video(tmp_path / "kitchen.mp4", KITCHEN[:12])
    capture = tmp_path / "rtps.pcapng"
    tshark = subprocess.Popen(
        ["tshark", "-i", "lo", "-f", "udp", "-w", str(capture), "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    time.sleep(2)  # tshark starts capturing
    domain = fresh_domain()
    first = Subscription(subscriber, domain, tmp_path / "first", [f"{DEPTH}=sensor_msgs/msg/Image:1"])
    # 12 frames recorded over 0.4 s, played at a tenth of their pace: 4 s live, for a node to join late.
    streaming = stream(
        service, tmp_path / "kitchen.mp4", domain, "--rate", "0.1", "--tf-parent", "camera_link", "--stride", "4"
    )
    first.first_sample()
    late = Subscription(subscriber, domain, tmp_path / "late", ["/tf_static=tf2_msgs/msg/TFMessage@transient_local:1"])
    (static,) = late.received()[0]
    _, err = streaming.communicate(timeout=300)
    assert streaming.returncode == 0, err
    first.process.kill()
    tshark.send_signal(signal.SIGINT)
    tshark.communicate(timeout=30)

    # The late node got the transform: the optical frame under camera_link, turned as REP 103 says.
    message = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(static, "tf2_msgs/msg/TFMessage")
    (transform,) = message.transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("camera_link", "camera_color_optical_frame")
    q = transform.transform.rotation
    x, y, z, w = q.x, q.y, q.z, q.w
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    # The optical z (forward) is the body's x, the optical x (right) its -y, the optical y (down) its -z.
    np.testing.assert_allclose(rotation @ np.eye(3), [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], atol=1e-12)

    # Absent parameters take the specifications' defaults: reliability RELIABLE for a writer and durability
    # VOLATILE (DDSI-RTPS 2.5, 9.6.2.2.5), data representation XCDR1 (DDS-XTypes 1.3, 7.6.3.1.1).
    writers = announced_writers(capture)
    for topic, (type_name, type_hash) in ROS2_EXPECTED.items():
        announced = writers[f"rt{topic}"]
        assert announced["type"] == type_name, topic
        assert int(announced["reliability"] or str(RELIABLE), 0) == RELIABLE, topic
        durability = TRANSIENT_LOCAL if topic == "/tf_static" else VOLATILE
        assert int(announced["durability"] or str(VOLATILE), 0) == durability, (topic, announced)
        assert announced["representation"] in (None, [str(XCDR1)]), (topic, announced)
        assert bytes.fromhex(announced["user_data"].replace(":", "")).decode() == f"typehash={type_hash};", topic


def test_bad_ros2_options_are_one_line_errors(service, tmp_path):  # noqa: F811
    photos = kitchen_folder(tmp_path / "photos", 1)
    for args, env, says in [
        (["--ros2"], {"ROS_DOMAIN_ID": "kitchen"}, "ROS_DOMAIN_ID 'kitchen': a ROS 2 domain is a whole number"),
        (["--ros2", "--ros-domain", "233"], {}, "--ros-domain"),
        (["--bag", str(tmp_path / "b"), "--ros-domain", "3"], {}, "--ros-domain is for --ros2"),
        (["--ros2", "--tf-parent", "camera_color_optical_frame"], {}, "name a frame other than the depth's own"),
    ]:
        result = subprocess.run(
            [sys.executable, "-m", "cli", "stream", str(photos), "--url", service, *args],
            cwd=REPO,
            env={**os.environ, **env},
            capture_output=True,
            text=True,
        )
        assert result.returncode != 0 and says in result.stderr, (args, result.stderr)
        assert "Traceback" not in result.stderr, result.stderr


def test_a_subscriber_that_hangs_costs_its_messages_not_the_stream(service, subscriber, tmp_path):  # noqa: F811
    # A node that matched, then stopped (SIGSTOP: it neither reads nor acknowledges): the stream goes on without
    # its acknowledgements, waits for them a bounded time at the end, and the bag beside it loses nothing.
    count = 8
    photos = kitchen_folder(tmp_path / "photos", count)
    domain = fresh_domain()
    hung = Subscription(
        subscriber, domain, tmp_path / "got", [f"{POINTS}=sensor_msgs/msg/PointCloud2:{count}"], timeout_s=300
    )
    streaming = stream(service, photos, domain, "--bag", str(tmp_path / "bag"), "--rate", "0")
    try:
        hung.first_sample()
        hung.process.send_signal(signal.SIGSTOP)
        out, err = streaming.communicate(timeout=300)
    finally:
        hung.process.send_signal(signal.SIGCONT)
        hung.process.kill()
    assert streaming.returncode == 0 and "Traceback" not in err, err
    # The stopped node never acknowledged the cloud topic it matched, and the last line says so.
    assert f"{count} frames written" in out and "ROS 2 topics not acknowledged by every subscriber" in out, out
    assert len(read_bag(tmp_path / "bag")[POINTS]) == count
