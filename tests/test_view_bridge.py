"""The live view's bridge (flagbot_sim/view/bridge.py): every name of the Foxglove protocol gets in, a refused
client is logged with what it offered, and hostile clients (garbage, slowloris, oversized frames, too many) leave
the view serving.
"""
import asyncio
import base64
import os
import random
import struct
import time

import pytest
import websockets
from foxglove_client import Client
from view_testlib import Publishing, stepped_design2

from flagbot_sim.view import bridge
from flagbot_sim.view.bridge import (LEGACY_SUBPROTOCOL, MAX_HEAD, MAX_MESSAGE, MAX_PENDING, BadRequest, FrameGuard,
                                     translate_request, translate_response)
from flagbot_sim.view.live import LiveView


def request(*protocol_headers: str, extra: str = "") -> bytes:
    lines = ["GET / HTTP/1.1", "Host: 127.0.0.1:8765", "Upgrade: websocket", "Connection: Upgrade",
             "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13", "Origin: file://",
             *(f"Sec-WebSocket-Protocol: {p}" for p in protocol_headers)]
    return ("\r\n".join(lines) + "\r\n" + extra + "\r\n").encode()


# ---------------------------------------------------------------------------------------------- handshake
def test_the_old_name_alone_is_renamed_for_the_sdk_and_nothing_else_changes():
    head = request(LEGACY_SUBPROTOCOL)
    out, legacy = translate_request(head)
    assert legacy is True
    assert out == head.replace(b"foxglove.websocket.v1", b"foxglove.sdk.v1")
    # several headers (RFC 6455 allows it) become one, where the first was
    out, legacy = translate_request(request("x.v0", LEGACY_SUBPROTOCOL))
    assert legacy and out.count(b"Sec-WebSocket-Protocol") == 1 and b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n" in out


@pytest.mark.parametrize("offer", ["foxglove.sdk.v1", "foxglove.sdk.v1.1", "foxglove.websocket.v1, foxglove.sdk.v1"])
def test_a_client_offering_an_sdk_name_is_passed_through_byte_for_byte(offer):
    head = request(offer)
    assert translate_request(head) == (head, False)


def test_the_sdks_answer_names_the_old_subprotocol_for_an_old_client():
    answer = (b"HTTP/1.1 101 Switching Protocols\r\nconnection: Upgrade\r\nupgrade: websocket\r\n"
              b"sec-websocket-protocol: foxglove.sdk.v1\r\nsec-websocket-accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n\r\n")
    out = translate_response(answer)
    assert out == answer.replace(b"sec-websocket-protocol: foxglove.sdk.v1", b"Sec-WebSocket-Protocol: "
                                 b"foxglove.websocket.v1")
    assert translate_response(answer.replace(b"foxglove.sdk.v1\r", b"foxglove.sdk.v1.1\r")) == \
        answer.replace(b"foxglove.sdk.v1\r", b"foxglove.sdk.v1.1\r")


def test_refusals_say_what_the_client_offered_in_printable_text():
    with pytest.raises(BadRequest, match=r"offered the WebSocket subprotocols 'foo\.v9', 'bar\?\?'") as e:
        translate_request(request("foo.v9, bar\x1b").replace(b"bar\x1b", b"bar\x1b\xff"))
    assert e.value.status == "400 Bad Request" and "foxglove.websocket.v1" in e.value.body
    with pytest.raises(BadRequest, match="offered no WebSocket subprotocol"):
        translate_request(request())
    with pytest.raises(BadRequest, match="not a WebSocket upgrade"):
        translate_request(request(LEGACY_SUBPROTOCOL).replace(b"Upgrade: websocket", b"Upgrade: h2c"))
    with pytest.raises(BadRequest, match="not an HTTP/1.1 GET"):
        translate_request(b"POST / HTTP/1.1\r\nHost: x\r\n\r\n")
    with pytest.raises(BadRequest, match="not an HTTP/1.1 GET"):
        translate_request(b"\x16\x03\x01garbage\r\n\r\n")


# ---------------------------------------------------------------------------------------------- frames
def frame(length: int, opcode: int = 1, fin: bool = True, payload: bool = True) -> bytes:
    """A masked client frame of ``length`` payload bytes (7-, 16- or 64-bit length as RFC 6455 requires)."""
    b0 = (0x80 if fin else 0) | opcode
    if length < 126:
        head = bytes([b0, 0x80 | length])
    elif length < 1 << 16:
        head = bytes([b0, 0x80 | 126]) + struct.pack(">H", length)
    else:
        head = bytes([b0, 0x80 | 127]) + struct.pack(">Q", length)
    return head + b"MASK" + (bytes(length) if payload else b"")


def feed_in_pieces(guard: FrameGuard, data: bytes, rng: random.Random):
    i = 0
    while i < len(data):
        k = rng.randint(1, 40)
        why = guard.feed(data[i:i + k])
        if why:
            return why
        i += k
    return None


def test_the_frame_guard_follows_frames_of_every_length_form_however_the_stream_is_cut():
    stream = frame(0) + frame(125) + frame(126) + frame(65535) + frame(65536) + frame(3, opcode=9) + \
        frame(700_000, fin=False) + frame(4, opcode=10) + frame(300_000, opcode=0)       # 1,000,000 bytes in all
    rng = random.Random(1)
    for _ in range(5):
        g = FrameGuard()
        assert feed_in_pieces(g, stream, rng) is None and g.at_boundary and not g.closed
    g = FrameGuard()
    assert g.feed(stream[:-1]) is None and not g.at_boundary
    g = FrameGuard()
    assert g.feed(frame(2, opcode=8)) is None and g.closed


def test_a_message_over_the_limit_is_refused_at_its_header_before_any_payload():
    g = FrameGuard()
    why = g.feed(frame(MAX_MESSAGE + 1, payload=False))
    assert why == f"it sent a message of {MAX_MESSAGE + 1} bytes or more (the limit is {MAX_MESSAGE})"
    # fragments add up: 3 x 400 kB is over 1 MiB at the third header; a finished message starts the count anew
    g = FrameGuard()
    assert g.feed(frame(400_000, fin=False) + frame(400_000, opcode=0, fin=False)) is None
    assert "1200000 bytes" in g.feed(frame(400_000, opcode=0, payload=False))
    g = FrameGuard()
    assert g.feed(frame(600_000) + frame(600_000) + frame(2 ** 20)) is None
    assert FrameGuard().feed(frame(2 ** 63 - 1, payload=False)) is not None


def test_refusal_lines_are_throttled_per_kind_and_the_held_back_ones_counted(monkeypatch):
    clock = [100.0]
    monkeypatch.setattr(bridge.time, "monotonic", lambda: clock[0])
    lines = []
    say = bridge._Throttle(lines.append, period=5.0)
    for i in range(4):
        say("request", f"garbage {i}")
        clock[0] += 1.0
    say("subprotocol", "offered foo")          # a flood of one kind does not hide another
    clock[0] += 5.0
    say("request", "garbage 4")
    assert lines == ["garbage 0", "offered foo", "garbage 4 (and 3 more such lines in the last 5 s)"]


# ---------------------------------------------------------------------------------------------- live
@pytest.fixture(scope="module")
def sim():
    return stepped_design2(2, steps=1)


class Serving(Publishing):
    """A LiveView on a free port publishing ``sim``; ``lines`` collects what it logs."""

    def __init__(self, sim, **kw):
        self.lines = []
        super().__init__(LiveView(port=0, log=self.lines.append, **kw), sim)

    def __exit__(self, *exc):
        super().__exit__(*exc)
        self.view.close(linger=0)


def run(coro, timeout=120):
    return asyncio.run(asyncio.wait_for(coro, timeout))


async def sees_the_robot(url: str, subprotocol: str = LEGACY_SUBPROTOCOL) -> None:
    """A client connects, subscribes to the scene and receives it (the view serves)."""
    c = await Client.connect(url, timeout=20, subprotocol=subprotocol)
    await c.subscribe({"/flagbot/scene"})
    topic, _, msg = await c.receive(timeout=20)
    assert topic == "/flagbot/scene" and any(e["id"] == "flagellum/0" for e in msg["entities"])
    await c.close()


async def closed_by_server(reader: asyncio.StreamReader, timeout: float = 30.0) -> bytes:
    """Everything the server sent until it closed the connection (EOF or reset)."""
    got = b""
    try:
        while True:
            chunk = await asyncio.wait_for(reader.read(65536), timeout)
            if not chunk:
                return got
            got += chunk
    except ConnectionError:
        return got


def test_both_names_connect_and_an_unknown_subprotocol_is_refused_with_a_line_naming_it(sim):
    with Serving(sim) as s:
        async def scenario():
            await sees_the_robot(s.view.url, LEGACY_SUBPROTOCOL)
            await sees_the_robot(s.view.url, "foxglove.sdk.v1")
            with pytest.raises(websockets.InvalidStatus) as e:
                await websockets.connect(s.view.url, subprotocols=["foxglove.ros.v9"])
            return e.value.response
        response = run(scenario())
    assert response.status_code == 400 and b"foxglove.websocket.v1" in response.body
    assert len(s.lines) == 1, s.lines
    assert s.lines[0].startswith("live view: refused a client from 127.0.0.1:")
    assert s.lines[0].endswith("it offered the WebSocket subprotocols 'foxglove.ros.v9'")
    assert s.view.bridge.relayed == 2 and s.view.bridge.refused == 1


def test_beyond_max_clients_a_client_is_told_503_and_one_gets_in_when_another_leaves(sim):
    with Serving(sim, max_clients=2) as s:
        async def scenario():
            a = await Client.connect(s.view.url, subprotocol=LEGACY_SUBPROTOCOL)
            b = await Client.connect(s.view.url)
            with pytest.raises(websockets.InvalidStatus) as e:
                await websockets.connect(s.view.url, subprotocols=[LEGACY_SUBPROTOCOL])
            await a.close()
            for _ in range(500):
                if s.view.bridge.connections < 2:
                    break
                await asyncio.sleep(0.02)
            await sees_the_robot(s.view.url)
            await b.close()
            return e.value.response.status_code
        assert run(scenario()) == 503
    assert any("2 clients are connected already" in line for line in s.lines), s.lines


def raw_upgrade(protocol: str = LEGACY_SUBPROTOCOL) -> bytes:
    key = base64.b64encode(os.urandom(16)).decode()
    return (f"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {protocol}\r\n\r\n"
            ).encode()


def test_hostile_clients_are_dropped_and_the_view_keeps_serving(sim):
    rng = random.Random(7)
    with Serving(sim) as s:
        port = s.view.port

        async def garbage():
            """Random bytes shaped like a request, a head over MAX_HEAD, binary junk: answered and closed."""
            answers = []
            for i in range(12):
                r, w = await asyncio.open_connection("127.0.0.1", port)
                if i == 0:
                    w.write(b"GET / HTTP/1.1\r\n" + b"X-Junk: " + b"a" * (MAX_HEAD + 10) + b"\r\n\r\n")
                else:
                    w.write(bytes(rng.randrange(256) for _ in range(rng.randint(1, 3000))) + b"\r\n\r\n")
                answers.append(await closed_by_server(r))
                w.close()
            return answers

        async def oversized():
            """A valid handshake, then a frame header claiming 2 MiB: closed before any payload is sent."""
            r, w = await asyncio.open_connection("127.0.0.1", port)
            w.write(raw_upgrade())
            head = await r.readuntil(b"\r\n\r\n")
            w.write(frame(2 * 2 ** 20, payload=False))
            await closed_by_server(r)
            w.close()
            return head

        async def slowloris(n: int):
            """``n`` connections whose request never completes (a few trickle a byte a second)."""
            conns = []
            for _ in range(n):
                try:
                    conns.append(await asyncio.open_connection("127.0.0.1", port))
                except OSError:
                    break
            for r, w in conns:
                w.write(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            return conns

        async def trickle(conns, stop: asyncio.Event):
            while not stop.is_set():
                for _, w in conns:
                    w.write(b"X")
                await asyncio.sleep(1.0)

        async def scenario():
            answers = await garbage()
            head = await oversized()
            lorises = await slowloris(MAX_PENDING + 40)
            stop = asyncio.Event()
            trickler = asyncio.ensure_future(trickle([c for c in lorises[:5]], stop))
            await asyncio.sleep(1.2)                 # the slowloris handshakes are > 1 s old now
            pending_when_served = s.view.bridge.pending
            await sees_the_robot(s.view.url)         # a real client gets in past them
            dropped = await asyncio.gather(*(closed_by_server(r) for r, _ in lorises))
            stop.set()
            await trickler
            for _, w in lorises:
                w.close()
            await sees_the_robot(s.view.url, "foxglove.sdk.v1")       # and the view still serves
            return answers, head, pending_when_served, dropped
        answers, head, pending_when_served, dropped = run(scenario())
        for _ in range(200):
            if s.view.bridge.connections == 0 and s.view.bridge.pending == 0:
                break
            time.sleep(0.05)
        assert s.view.bridge.connections == 0 and s.view.bridge.pending == 0
    assert answers[0].startswith(b"HTTP/1.1 431 ")
    assert all(a.startswith(b"HTTP/1.1 400 Bad Request") for a in answers[1:])
    assert head.startswith(b"HTTP/1.1 101 ")
    # the slowloris connections were waiting when the real client came, and every one was closed by the server:
    # the 40 over MAX_PENDING at once (503, or dropped as the oldest), the rest at the request deadline, the
    # trickling ones too (the deadline is for the whole head, not between bytes)
    assert pending_when_served >= 200
    assert len(dropped) == MAX_PENDING + 40
    assert all(d == b"" or d.startswith(b"HTTP/1.1 503 ") for d in dropped)
    assert sum(d != b"" for d in dropped) <= 40
    text = "\n".join(s.lines)
    assert "a request head over 16384 bytes" in text and "it sent a message of 2097152 bytes or more" in text
    assert "no complete request within 5 s" in text
    assert s.view.bridge.relayed >= 3
