"""Answers live on a Foxglove WebSocket server (the ``foxglove-sdk`` package, subprotocol
``foxglove.sdk.v1``, the protocol ``foxglove_bridge`` speaks): one channel per topic, carrying the ROS 2
messages ``ros_messages`` makes as CDR with their ``ros2msg`` schemas, so Foxglove's Image, 3D and camera
panels show them as they would a ROS robot's. Each message is logged with the frame's own stamp.

/tf_static is latched, as tf2's static broadcaster makes it in ROS 2: a client that subscribes to it gets the
transform again with the next frame, so a Foxglove opened after the stream began still places the cloud."""

from __future__ import annotations

from typing import Any

from clients.sinks import DecodedFrame
from clients.sinks.ros_messages import TF_STATIC, Message, RosMessages
from contract.errors import UserError

INSTALL = "the Foxglove output needs the ros extra: pip install -e '.[ros]'"


def address(given: str) -> tuple[str, int]:
    """``[HOST:]PORT`` as (host, port); the host is 127.0.0.1 unless given (0.0.0.0 for every interface)."""
    host, _, port = given.rpartition(":")
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise UserError(f"--foxglove {given!r}: give [HOST:]PORT, such as 8765 or 0.0.0.0:8765")
    return host or "127.0.0.1", int(port)


class StaticWanted:
    """The server's listener: notes that a client subscribed to /tf_static, for the next frame to log it
    again (logging from the server's own callback is left alone). The server calls ``on_subscribe`` and
    ``on_unsubscribe`` whatever its capabilities, so both are here (a missing one is an error it prints
    at every client that leaves)."""

    def __init__(self) -> None:
        self.wanted = False

    def on_subscribe(self, client: Any, channel: Any) -> None:
        if channel.topic == TF_STATIC:
            self.wanted = True

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        """Nothing to do: a channel nobody takes costs the server nothing."""


class FoxgloveSink:
    def __init__(self, given: str, messages: RosMessages):
        try:
            import foxglove
        except ImportError:
            raise UserError(INSTALL) from None
        host, port = address(given)
        self.messages, self.foxglove, self.host = messages, foxglove, host
        self.context = foxglove.Context()
        self.subscribed = StaticWanted()
        try:
            self.server = foxglove.start_server(
                name="rgb2cloud", host=host, port=port, context=self.context, server_listener=self.subscribed
            )
        except RuntimeError as e:  # the port is taken, the host is not this machine's
            raise UserError(f"--foxglove {given}: cannot serve there: {e}") from None
        self.channels: dict[str, Any] = {}
        self.static: Message | None = None

    @property
    def port(self) -> int:
        """The port it serves on (the one the system gave, for port 0)."""
        return self.server.port

    def write(self, answer: DecodedFrame) -> None:
        latched = []
        if not self.channels:
            self.static = self.messages.static(answer.stamp_ns)  # stamped with the first frame, as tf2's is
            latched = [self.static] if self.static is not None else []
        elif self.subscribed.wanted and self.static is not None:
            self.subscribed.wanted = False
            latched = [self.static]
        for message in latched + list(self.messages(answer)):
            if message.topic not in self.channels:
                schema = self.foxglove.Schema(
                    name=message.msgtype, encoding="ros2msg", data=self.messages.definition(message.msgtype).encode()
                )
                self.channels[message.topic] = self.foxglove.Channel(
                    message.topic, schema=schema, message_encoding="cdr", context=self.context
                )
            # Logged at this frame's time, a latched /tf_static sent again too (its header keeps the first
            # frame's stamp, as tf2's does): a channel's log time never goes back for a client that joins late.
            self.channels[message.topic].log(message.cdr, log_time=answer.stamp_ns)

    def close(self) -> None:
        self.server.stop()
