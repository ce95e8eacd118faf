"""A minimal Foxglove WebSocket client for the tests, written from the protocol as the Foxglove app speaks it.

It connects with the subprotocol ``foxglove.sdk.v1`` (or the one it is given: ``foxglove.websocket.v1``), reads ``serverInfo`` and ``advertise`` (JSON text frames),
subscribes, and decodes binary ``messageData`` frames (opcode 1, subscription id u32, log time u64, payload): a
protobuf channel with the FileDescriptorSet the server advertised (google.protobuf, as the app does with its own
decoder), a JSON channel with json. Nothing of the server's SDK is used.
"""
from __future__ import annotations

import asyncio
import base64
import json
import struct

import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.json_format import MessageToDict

SUBPROTOCOL = "foxglove.sdk.v1"


def protobuf_class(schema_b64: str, name: str):
    """The message class ``name`` from a base64 FileDescriptorSet (files added dependencies first)."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    pending = list(fds.file)
    added: set[str] = set()
    while pending:
        ready = [f for f in pending if all(d in added for d in f.dependency)]
        assert ready, f"unresolvable dependencies in the advertised schema of {name}"
        for f in ready:
            pool.Add(f)
            added.add(f.name)
            pending.remove(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


class Client:
    def __init__(self, ws):
        self.ws = ws
        self.server_info: dict | None = None
        self.channels: dict[int, dict] = {}       # channel id -> advertised channel
        self.subscriptions: dict[int, dict] = {}  # subscription id -> channel
        self._decoders = {}

    @classmethod
    async def connect(cls, url: str, timeout: float = 5.0, subprotocol: str = SUBPROTOCOL) -> "Client":
        """Connected, with the server's info and channels read; ``subprotocol`` the only one offered."""
        ws = await asyncio.wait_for(websockets.connect(url, subprotocols=[subprotocol], max_size=None), timeout)
        assert ws.subprotocol == subprotocol
        c = cls(ws)
        while c.server_info is None or not c.channels:
            frame = await asyncio.wait_for(ws.recv(), timeout)
            if isinstance(frame, str):      # a binary frame (the time, while a run publishes) is not control
                c._control(json.loads(frame))
        return c

    def _control(self, msg: dict) -> None:
        if msg["op"] == "serverInfo":
            self.server_info = msg
        elif msg["op"] == "advertise":
            for ch in msg["channels"]:
                self.channels[ch["id"]] = ch
        elif msg["op"] == "unadvertise":
            for i in msg["channelIds"]:
                self.channels.pop(i, None)

    def topics(self) -> dict[str, dict]:
        return {ch["topic"]: ch for ch in self.channels.values()}

    async def subscribe(self, topics=None) -> None:
        subs = []
        for ch in self.channels.values():
            if topics is None or ch["topic"] in topics:
                sid = len(self.subscriptions) + 1
                self.subscriptions[sid] = ch
                subs.append({"id": sid, "channelId": ch["id"]})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def decode(self, ch: dict, payload: bytes):
        if ch["encoding"] == "json":
            return json.loads(payload)
        assert ch["encoding"] == "protobuf" and ch["schemaEncoding"] == "protobuf"
        if ch["id"] not in self._decoders:
            self._decoders[ch["id"]] = protobuf_class(ch["schema"], ch["schemaName"])
        msg = self._decoders[ch["id"]].FromString(payload)
        return MessageToDict(msg, preserving_proto_field_name=True, always_print_fields_with_no_presence=True)

    async def receive(self, timeout: float = 5.0):
        """The next data message as (topic, log_time_ns, decoded); control messages are absorbed, time skipped."""
        while True:
            frame = await asyncio.wait_for(self.ws.recv(), timeout)
            if isinstance(frame, str):
                self._control(json.loads(frame))
                continue
            if frame[0] != 1:          # 2 = time, others: not data
                continue
            sid, log_time = struct.unpack_from("<IQ", frame, 1)
            ch = self.subscriptions[sid]
            return ch["topic"], log_time, self.decode(ch, frame[13:])

    async def collect(self, topics: set[str], timeout: float = 5.0) -> dict:
        """Receive until every topic in ``topics`` has a message; topic -> [(log_time, msg), ...]."""
        got: dict[str, list] = {}
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while not topics <= set(got):
            topic, lt, msg = await self.receive(max(0.01, end - loop.time()))
            got.setdefault(topic, []).append((lt, msg))
        return got

    async def close(self) -> None:
        await self.ws.close()
