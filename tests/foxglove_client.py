"""A small Foxglove WebSocket protocol client for tests.

The protocol is the one specified as `foxglove.websocket.v1`; the foxglove-sdk server names it
`foxglove.sdk.v1` in the handshake (the same messages under a new name) and accepts only that
name, so the client offers both names, as the Foxglove app does. It does what the Foxglove app
does with a live connection: reads the server's `serverInfo` and `advertise` messages,
subscribes to channels by topic, and decodes `messageData` frames with the channel's advertised
schema (protobuf through the FileDescriptorSet the server sends, JSON as JSON).
"""

from __future__ import annotations

import base64
import json
import struct
import time
from dataclasses import dataclass
from typing import Any

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
OP_MESSAGE_DATA = 1


@dataclass
class Received:
    """One decoded message: its topic, the server's timestamp (ns) and the message as a dict."""

    topic: str
    log_time_ns: int
    message: dict[str, Any]


class FoxgloveClient:
    """Connects to `url`, collects advertisements, subscribes and decodes messages."""

    def __init__(self, url: str, timeout_s: float = 10.0) -> None:
        from websockets.sync.client import connect

        # Entered as a context manager: the way websockets keeps supporting across versions.
        self._conn = connect(url, subprotocols=list(SUBPROTOCOLS), open_timeout=timeout_s)  # type: ignore[arg-type]
        self.ws = self._conn.__enter__()
        self.subprotocol = self.ws.subprotocol
        self.server_info: dict[str, Any] | None = None
        self.channels: dict[str, dict[str, Any]] = {}  # topic -> advertised channel
        self._decoders: dict[int, tuple[str, Any]] = {}  # subscription id -> (topic, decode)
        self._next_sub = 1

    def close(self) -> None:
        self._conn.__exit__(None, None, None)

    def _handle_text(self, text: str) -> None:
        msg = json.loads(text)
        if msg.get("op") == "serverInfo":
            self.server_info = msg
        elif msg.get("op") == "advertise":
            for ch in msg["channels"]:
                self.channels[ch["topic"]] = ch
        elif msg.get("op") == "unadvertise":
            ids = set(msg["channelIds"])
            self.channels = {t: c for t, c in self.channels.items() if c["id"] not in ids}

    def wait_topics(self, topics: list[str], timeout_s: float) -> None:
        """Read until every topic in `topics` is advertised; AssertionError after `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        while not all(t in self.channels for t in topics):
            left = deadline - time.monotonic()
            assert left > 0, f"not advertised: {set(topics) - set(self.channels)}"
            try:
                data = self.ws.recv(timeout=left)
            except TimeoutError:
                continue
            if isinstance(data, str):
                self._handle_text(data)

    def subscribe(self, topic: str) -> None:
        """Subscribe to an advertised topic and prepare its decoder."""
        ch = self.channels[topic]
        sub_id = self._next_sub
        self._next_sub += 1
        self._decoders[sub_id] = (topic, _decoder(ch))
        self.ws.send(
            json.dumps(
                {"op": "subscribe", "subscriptions": [{"id": sub_id, "channelId": ch["id"]}]}
            )
        )

    def next_message(self, timeout_s: float) -> Received | None:
        """The next decoded message of any subscription, or None after `timeout_s`."""
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            try:
                data = self.ws.recv(timeout=left)
            except TimeoutError:
                return None
            if isinstance(data, str):
                self._handle_text(data)
                continue
            if data[0] != OP_MESSAGE_DATA:
                continue
            sub_id, log_time_ns = struct.unpack_from("<IQ", data, 1)
            entry = self._decoders.get(sub_id)
            if entry is None:
                continue
            topic, decode = entry
            return Received(topic, log_time_ns, decode(bytes(data[13:])))


def _decoder(channel: dict[str, Any]) -> Any:
    """A function bytes -> dict for an advertised channel (protobuf or JSON)."""
    if channel["encoding"] == "json":
        return lambda b: json.loads(b)
    assert channel["encoding"] == "protobuf", channel
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from google.protobuf.json_format import MessageToDict

    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))

    def decode(b: bytes) -> dict[str, Any]:
        out: dict[str, Any] = MessageToDict(
            cls.FromString(b),
            preserving_proto_field_name=True,
            always_print_fields_with_no_presence=True,
        )
        return out

    return decode
