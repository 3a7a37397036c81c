"""Answers as a ROS 2 bag (MCAP storage, written with ``rosbags``), as a depth camera's driver records it.
The bag's metadata is written when the writer closes, which ``close`` does on any exit, Ctrl-C included, so
what was written stays a readable bag."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from clients.sinks import DecodedFrame
from clients.sinks.ros_messages import TF_STATIC, Message, RosMessages
from contract.errors import UserError


def _tf_static_qos() -> Any:
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    never = QosTime(0x7FFFFFFF, 0xFFFFFFFF)  # rmw's "infinite" as ros2 bag record writes it
    return Qos(
        QosHistory.KEEP_LAST,
        1,
        QosReliability.RELIABLE,
        QosDurability.TRANSIENT_LOCAL,
        never,
        never,
        QosLiveliness.AUTOMATIC,
        never,
        False,
    )


class BagSink:
    def __init__(self, path: Path, messages: RosMessages):
        from rosbags.rosbag2 import StoragePlugin, Writer

        if Path(path).exists():
            raise UserError(f"{path}: exists; a bag is written into a new folder")
        self.messages = messages
        self.writer = Writer(Path(path), version=8, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        self._connections: dict[str, Any] = {}
        self.frames = 0

    def write(self, answer: DecodedFrame) -> None:
        if self.frames == 0 and (static := self.messages.static(answer.stamp_ns)) is not None:
            self._write(static)
        for message in self.messages(answer):
            self._write(message)
        self.frames += 1

    def _write(self, message: Message) -> None:
        if message.topic not in self._connections:
            # /tf_static as tf2's static broadcaster offers it, so that ros2 bag play latches it
            qos = [_tf_static_qos()] if message.topic == TF_STATIC else []
            self._connections[message.topic] = self.writer.add_connection(
                message.topic, message.msgtype, typestore=self.messages.store, offered_qos_profiles=qos
            )
        self.writer.write(self._connections[message.topic], message.stamp_ns, message.cdr)

    def close(self) -> None:
        self.writer.close()
