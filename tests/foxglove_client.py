"""A Foxglove WebSocket client for the tests, speaking the protocol as the Foxglove app does: offer the
subprotocols, read serverInfo and advertise, subscribe to every channel, decode the binary messageData frames
(opcode 1, uint32 subscription id, uint64 log time ns, payload; little-endian), and decode the payloads by
their advertised schema: protobuf from the advertised FileDescriptorSet, JSON as JSON (strictly: no NaN)."""

from __future__ import annotations

import asyncio
import base64
import json
import struct
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import websockets

#: what the Foxglove app offers (foxglove-sdk servers speak foxglove.sdk.v1; older servers foxglove.websocket.v1)
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 1


@dataclass
class Received:
    topic: str
    log_time_ns: int
    payload: bytes


@dataclass
class Capture:
    subprotocol: str = ""
    server_info: dict = field(default_factory=dict)
    channels: dict[int, dict] = field(default_factory=dict)  # channel id -> advertisement
    messages: list[Received] = field(default_factory=list)
    closed_by_server: bool = False

    def on(self, topic: str) -> list[Received]:
        return [m for m in self.messages if m.topic == topic]

    def channel(self, topic: str) -> dict:
        (adv,) = [c for c in self.channels.values() if c["topic"] == topic]
        return adv

    def decode(self, message: Received) -> Any:
        """The payload as the app reads it: a protobuf message, or a JSON document."""
        adv = self.channel(message.topic)
        if adv["encoding"] == "json":
            return json.loads(message.payload, parse_constant=_refuse_constant)
        if adv["encoding"] == "protobuf":
            return protobuf_class(adv).FromString(message.payload)
        raise AssertionError(f"{message.topic}: unexpected encoding {adv['encoding']}")


def _refuse_constant(name: str):
    raise ValueError(f"invalid JSON constant {name} (a Foxglove app cannot parse it)")


_CLASSES: dict[tuple[str, str], type] = {}


def protobuf_class(adv: dict) -> type:
    """The message class of a protobuf channel, built from its advertised schema (base64 FileDescriptorSet)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    key = (adv["schemaName"], adv["schema"])
    if key not in _CLASSES:
        fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(adv["schema"]))
        pool = descriptor_pool.DescriptorPool()
        for f in fds.file:
            pool.Add(f)
        _CLASSES[key] = message_factory.GetMessageClass(pool.FindMessageTypeByName(adv["schemaName"]))
    return _CLASSES[key]


async def _connect(url: str, deadline: float):
    while True:
        try:
            return await websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None, proxy=None,
                                            open_timeout=5)
        except (OSError, websockets.exceptions.InvalidHandshake, asyncio.TimeoutError):
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.05)


async def capture(url: str, *, connect_timeout_s: float, stop: Callable[[], bool], quiet_s: float = 1.0,
                  timeout_s: float = 120.0, topics: set[str] | None = None) -> Capture:
    """Connect (retrying until ``connect_timeout_s``), subscribe to every advertised channel (or ``topics``) and
    record what arrives until the server closes the connection, or ``stop()`` is true and nothing came for
    ``quiet_s``, or ``timeout_s``."""
    out = Capture()
    start = time.monotonic()
    ws = await _connect(url, start + connect_timeout_s)
    out.subprotocol = ws.subprotocol or ""
    subscriptions: dict[int, str] = {}
    try:
        while time.monotonic() - start < timeout_s:
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=quiet_s)
            except asyncio.TimeoutError:
                if stop():
                    break
                continue
            if isinstance(frame, bytes):
                op, sub_id, log_time = struct.unpack_from("<BIQ", frame)
                if op == MESSAGE_DATA and sub_id in subscriptions:
                    out.messages.append(Received(subscriptions[sub_id], log_time, frame[13:]))
                continue
            doc = json.loads(frame)
            if doc["op"] == "serverInfo":
                out.server_info = doc
            elif doc["op"] == "advertise":
                new = [c for c in doc["channels"] if topics is None or c["topic"] in topics]
                for c in new:
                    out.channels[c["id"]] = c
                subs = []
                for c in new:
                    sub_id = len(subscriptions) + 1
                    subscriptions[sub_id] = c["topic"]
                    subs.append({"id": sub_id, "channelId": c["id"]})
                if subs:
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
    except websockets.exceptions.ConnectionClosed:
        out.closed_by_server = True
    finally:
        await ws.close()
    return out
