"""Answers as a ROS 2 bag (MCAP storage, written with ``rosbags``), as a depth camera's driver records it.
The bag's metadata is written when the writer closes, which ``close`` does on any exit, Ctrl-C included, so
what was written stays a readable bag."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from clients.sinks import Answer
from clients.sinks.ros_messages import RosMessages
from contract.errors import UserError


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

    def write(self, answer: Answer) -> None:
        for message in self.messages(answer):
            if message.topic not in self._connections:
                self._connections[message.topic] = self.writer.add_connection(
                    message.topic, message.msgtype, typestore=self.messages.store
                )
            self.writer.write(self._connections[message.topic], message.stamp_ns, message.cdr)
        self.frames += 1

    def close(self) -> None:
        self.writer.close()
