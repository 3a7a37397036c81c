"""Answers live as ROS 2 topics over DDS, with no ROS install: Eclipse Cyclone DDS (the ``cyclonedds``
package, in the ros extra) publishes the messages ``ros_messages`` makes, as a ROS 2 node's publishers would.

ROS 2 is DDS underneath, and a subscription matches a DDS writer that follows its conventions:

- topic ``/a/b`` is the DDS topic ``rt/a/b``; type ``sensor_msgs/msg/Image`` is ``sensor_msgs::msg::dds_::Image_``;
- the types are final, so the payload is plain XCDR1 (the CDR a bag holds), and the writers offer only that;
- QoS as a ROS 2 publisher's default: RELIABLE, VOLATILE, KEEP_LAST 10; ``/tf_static`` as tf2's static
  broadcaster's: RELIABLE, TRANSIENT_LOCAL, KEEP_LAST 1, so a node that starts later still gets it;
- each writer's USER_DATA says ``typehash=RIHS01_...;``, the type's hash that ROS 2 Jazzy and later compare.

The DDS types are made from rosbags' definitions of the ROS messages (``dds_type``); each sample is written as
the CDR bytes ``ros_messages`` serialised, so the bag, Foxglove and DDS carry the very same bytes. ``uint8``
fields go as XTypes ``octet``: the Cyclone DDS 0.10 that ROS 2 Humble and Jazzy ship cannot read the type
objects of the newer ``uint8`` kind, and on the wire the two are the same byte.

What is not done: the process is not a ROS node, so ``ros2 node list`` does not show it (that list comes from
rmw's own ``ros_discovery_info`` topic); ``ros2 topic list``, ``echo`` and ``hz``, rviz2 and any subscribing
node see the topics.
"""

from __future__ import annotations

import os
from typing import Any

from clients.sinks import DecodedFrame
from clients.sinks.ros_messages import TF_STATIC, Message, RosMessages
from contract.errors import UserError

INSTALL = "the ROS 2 output needs the ros extra: pip install -e '.[ros]'"
#: A ROS 2 publisher's default history depth (rclcpp's and rclpy's ``QoSProfile(depth=10)``).
DEPTH = 10
#: How long a write may wait for a reliable subscriber to take what it was sent before the frame's message is
#: given up on (counted in ``dropped``): a stalled subscriber slows the stream, never stops it.
MAX_BLOCKING_S = 1.0


def domain_id(given: int | None) -> int:
    """``--ros-domain``, else ``ROS_DOMAIN_ID`` as ROS 2 reads it, else 0."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip() if given is None else str(given)
    if not text:
        return 0
    if not text.isdigit() or not 0 <= int(text) <= 232:
        source = "--ros-domain" if given is not None else "ROS_DOMAIN_ID"
        raise UserError(f"{source} {text!r}: a ROS 2 domain is a whole number from 0 to 232")
    return int(text)


class DdsTypes:
    """The Cyclone DDS types of ROS 2 messages, made from rosbags' definitions (one ``RosMessages.store``)."""

    def __init__(self, store: Any):
        from cyclonedds.idl import types

        self.store, self.made = store, {}
        self.base = {
            "bool": bool,
            "byte": types.byte,
            "char": types.byte,
            "uint8": types.byte,  # see the module's docstring
            "int8": types.int8,
            "int16": types.int16,
            "uint16": types.uint16,
            "int32": types.int32,
            "uint32": types.uint32,
            "int64": types.int64,
            "uint64": types.uint64,
            "float32": types.float32,
            "float64": types.float64,
        }

    def __call__(self, msgtype: str) -> type:
        """``sensor_msgs/msg/Image`` as the final struct ``sensor_msgs::msg::dds_::Image_``."""
        if msgtype not in self.made:
            from cyclonedds.idl import annotations, make_idl_struct

            package, kind, name = msgtype.split("/")
            _, fields = self.store.fielddefs[msgtype]
            made = make_idl_struct(
                name, f"{package}::{kind}::dds_::{name}_", {field: self._field(desc) for field, desc in fields}
            )
            self.made[msgtype] = annotations.final(made)
        return self.made[msgtype]

    def _field(self, desc: tuple[Any, Any]) -> Any:
        from cyclonedds.idl import types
        from rosbags.typesys.base import Nodetype

        kind, detail = desc
        if kind == Nodetype.BASE:
            name, bound = detail
            if name == "string":
                return types.bounded_str[bound] if bound else str
            return self.base[name]
        if kind == Nodetype.NAME:
            return self(detail)
        element, length = detail
        if kind == Nodetype.ARRAY:
            return types.array[self._field(element), length]
        return types.sequence[self._field(element), length] if length else types.sequence[self._field(element)]


def serialised(dds_type: type) -> type:
    """A sample of ``dds_type`` that is already CDR: the writer sends its bytes as they are."""

    class Serialised(dds_type):  # type: ignore[valid-type,misc]
        def __init__(self, cdr: bytes):
            self.cdr = cdr

        def serialize(self, *args: Any, **kwargs: Any) -> bytes:
            return self.cdr

    return Serialised


class Ros2Sink:
    """One DDS participant in ``domain`` and a writer for each topic, all opened at once: subscribers discover
    them while the stream connects, so the first frame reaches those already listening."""

    def __init__(self, domain: int, messages: RosMessages):
        try:
            from cyclonedds.domain import DomainParticipant
        except ImportError:
            raise UserError(INSTALL) from None
        self.messages, self.domain = messages, domain
        self.types = DdsTypes(messages.store)
        try:
            self.participant = DomainParticipant(domain)
        except Exception as e:  # cyclonedds.core.DDSException: a bad CYCLONEDDS_URI, no usable interface
            raise UserError(f"ROS 2 (DDS domain {domain}): cannot join: {e}") from None
        self.writers = {topic: self._writer(topic, msgtype) for topic, msgtype in messages.topic_types()}
        self.dropped = 0
        self.unacknowledged: list[str] = []
        self._sent_static = False

    def write(self, answer: DecodedFrame) -> None:
        if not self._sent_static:
            self._sent_static = True
            if (static := self.messages.static(answer.stamp_ns)) is not None:
                self._publish(static)
        for message in self.messages(answer):
            self._publish(message)

    def _publish(self, message: Message) -> None:
        from cyclonedds.core import DDSException

        writer, sample = self.writers[message.topic]
        try:
            writer.write(sample(message.cdr))
        except DDSException as e:
            if e.code != DDSException.DDS_RETCODE_TIMEOUT:
                raise UserError(f"ROS 2: cannot publish {message.topic}: {e}") from None
            self.dropped += 1  # a reliable subscriber did not take it within MAX_BLOCKING_S

    def _writer(self, topic: str, msgtype: str) -> tuple[Any, type]:
        """A writer of ``msgtype`` on ``topic`` with a ROS 2 publisher's QoS, and its samples' class."""
        from cyclonedds.core import Policy, Qos
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        dds_type = self.types(msgtype)
        latched = topic == TF_STATIC
        qos = Qos(
            Policy.Reliability.Reliable(max_blocking_time=duration(seconds=MAX_BLOCKING_S)),
            Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile,
            Policy.History.KeepLast(1 if latched else DEPTH),
            Policy.DataRepresentation(use_cdrv0_representation=True),
            Policy.Userdata(f"typehash={self.messages.store.hash_rihs01(msgtype)};".encode()),
        )
        writer = DataWriter(self.participant, Topic(self.participant, f"rt{topic}", dds_type), qos)
        return writer, serialised(dds_type)

    def close(self) -> None:
        """Waits (a second at most per writer) for subscribers to acknowledge what was sent, then leaves
        whether they did or not, noting the topics whose acknowledgements did not all come."""
        from cyclonedds.core import DDSException

        try:
            self.unacknowledged = [topic for topic, (writer, _) in self.writers.items() if not acknowledged(writer)]
        except DDSException as e:
            raise UserError(f"ROS 2: waiting for subscribers to acknowledge: {e}") from None
        finally:
            self.participant = None
            self.writers.clear()

    def shortfall(self) -> str:
        """What subscribers did not get, for the stream's last line ("" if they got everything)."""
        parts = [f"{self.dropped} ROS 2 messages a subscriber took too slowly to get"] if self.dropped else []
        if self.unacknowledged:
            topics = ", ".join(self.unacknowledged)
            parts.append(
                f"{len(self.unacknowledged)} ROS 2 topics not acknowledged by every subscriber at the end: {topics}"
            )
        return "".join(f", {part}" for part in parts)


def acknowledged(writer: Any) -> bool:
    """Whether every matched reliable reader acknowledged what ``writer`` sent, waiting a second at most."""
    from cyclonedds.util import duration

    try:
        return writer.wait_for_acks(duration(seconds=1))
    except AttributeError as e:
        # cyclonedds 11.0.1 looks its timeout code up on Exception, not DDSException, and so raises this for
        # every result but success: a timeout or any other failure to get the acknowledgements, which all
        # read as "not acknowledged" here. Any other AttributeError is a bug and goes on up.
        if "DDS_RETCODE_TIMEOUT" not in str(e):
            raise
        return False
