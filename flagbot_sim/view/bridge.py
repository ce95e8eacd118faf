"""The live view's front door: a TCP relay that lets every Foxglove-protocol client reach the SDK's server.

foxglove-sdk accepts only the WebSocket subprotocols ``foxglove.sdk.v1`` / ``foxglove.sdk.v1.1``; the npm client
``@foxglove/ws-protocol``, Lichtblick and older Foxglove Studio offer only ``foxglove.websocket.v1``, the same
protocol under its first name, and the SDK answers them HTTP 400. :class:`Bridge` listens where the user asked
(127.0.0.1 by default), reads each client's HTTP upgrade request itself, and relays the connection to the SDK's
server on a loopback port of its own. For a client that offers only ``foxglove.websocket.v1`` it renames the
offer to ``foxglove.sdk.v1`` on the way in and the server's choice back on the way out; everything after the
handshake is relayed byte for byte (the WebSocket frames are the same under either name). A client that offers
none of the names is answered 400 here, and the log says what it offered.

Why a byte relay and not a protocol server of our own: the SDK keeps doing the protocol (channels, schemas,
subscriptions, per-client backlogs that drop old data for a slow client), and the relay is one handshake parse
plus two copy loops; it adds 0.08-0.18 ms per message on loopback (``benchmarks/live_view_clients.py`` prints it).

Hostile clients meet limits before anything reaches the SDK: a request head larger than :data:`MAX_HEAD` bytes
or not complete within ``handshake_timeout`` is dropped (slowloris; when :data:`MAX_PENDING` handshakes are
pending, the oldest is dropped, so a real client always gets in); a request that is not a WebSocket upgrade is
answered 400; at most ``max_clients`` connections are relayed (503 beyond); and the client's frames are checked as
they pass (headers only, no payload is buffered): a message larger than ``max_message`` bytes closes that
connection (clients send only small JSON requests; the SDK's own limit is 16 MiB per frame). A slow reader
holds back the relay, which holds back the SDK's socket, so the SDK's backlog policy stays in force.

Memory: the SDK allocates per-client buffers with glibc's malloc in its own threads; freed, they stay in those
threads' arenas and RSS stays up (+14 to +18 MB after 200 clients). Once departures settle, the relay asks glibc
to return free pages to the system (``malloc_trim``): +2.4 to +4.9 MB then, flat up to 2400 clients
(docs/live_view.md has the figures).
"""
from __future__ import annotations

import asyncio
import ctypes
import socket
import threading
import time
from collections import OrderedDict
from typing import Callable

#: the names of the protocol the SDK accepts, and the first name, which older clients offer
SDK_SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.sdk.v1.1")
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
SUBPROTOCOLS = (LEGACY_SUBPROTOCOL, *SDK_SUBPROTOCOLS)

MAX_HEAD = 16 * 1024            # bytes of an HTTP request head (browsers send < 2 KiB)
MAX_PENDING = 256               # handshakes in progress at once; then the oldest goes if it has had a second
MAX_CLIENTS = 100               # relayed connections at once
MAX_MESSAGE = 1 << 20           # bytes of one client message (the largest request a client sends is < 1 KiB)
HANDSHAKE_TIMEOUT = 5.0         # s to send a complete request head
TRIM_DELAY = 0.5                # s after the last departure before free memory is returned
LOG_PERIOD = 5.0                # s: at most one line per kind of refusal per period (a flood is counted)


def _glibc_malloc_trim():
    try:
        return ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):        # not glibc (musl, macOS): nothing to trim with
        return None


_MALLOC_TRIM = _glibc_malloc_trim()


def release_free_memory() -> bool:
    """Return the free pages of every malloc arena to the system (glibc ``malloc_trim(0)``); False if unavailable."""
    if _MALLOC_TRIM is None:
        return False
    _MALLOC_TRIM(0)
    return True


def printable(text: str, limit: int = 120) -> str:
    """``text`` safe for one log line: control and non-ASCII characters as ``?``, cut to ``limit`` characters."""
    s = "".join(c if " " <= c <= "~" else "?" for c in text)
    return s if len(s) <= limit else s[:limit] + "..."


class BadRequest(ValueError):
    """A request head this server refuses: the status line to answer and the reason to log."""

    def __init__(self, status: str, reason: str, body: str, kind: str = "request"):
        super().__init__(reason)
        self.status, self.reason, self.body, self.kind = status, reason, body, kind


def _lines(head: bytes) -> list[str]:
    return head.decode("latin-1").split("\r\n")[:-2]      # head ends with CRLF CRLF


def _header_values(lines: list[str], name: str) -> list[str]:
    return [ln.split(":", 1)[1].strip() for ln in lines[1:] if ln.split(":", 1)[0].strip().lower() == name]


def offered_subprotocols(lines: list[str]) -> list[str]:
    """The subprotocols of every ``Sec-WebSocket-Protocol`` header, in order (RFC 6455 allows several headers)."""
    return [t.strip() for v in _header_values(lines, "sec-websocket-protocol") for t in v.split(",") if t.strip()]


def _set_header(lines: list[str], name: str, value: str) -> list[str]:
    """``lines`` with every ``name`` header replaced by one ``name: value`` where the first one was."""
    out, done = [lines[0]], False
    for ln in lines[1:]:
        if ln.split(":", 1)[0].strip().lower() == name.lower():
            if not done:
                out.append(f"{name}: {value}")
                done = True
        else:
            out.append(ln)
    return out


def _join(lines: list[str]) -> bytes:
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


def translate_request(head: bytes) -> tuple[bytes, bool]:
    """The request head to send the SDK, and whether the client speaks only the legacy name.

    Raises :class:`BadRequest` for anything but a WebSocket upgrade offering one of :data:`SUBPROTOCOLS`."""
    lines = _lines(head)
    request = lines[0].split(" ") if lines else []
    if len(request) != 3 or request[0] != "GET" or request[2] != "HTTP/1.1" or \
            any(":" not in ln for ln in lines[1:]):
        raise BadRequest("400 Bad Request", f"not an HTTP/1.1 GET request ({printable(lines[0] if lines else '', 40)!r})",
                         "this is a Foxglove WebSocket server: connect a Foxglove client to ws://HOST:PORT\n")
    if not any("websocket" in v.lower() for v in _header_values(lines, "upgrade")) or \
            not _header_values(lines, "sec-websocket-key"):
        raise BadRequest("400 Bad Request", "not a WebSocket upgrade request",
                         "this is a Foxglove WebSocket server: connect a Foxglove client to ws://HOST:PORT\n")
    offered = offered_subprotocols(lines)
    if any(p in SDK_SUBPROTOCOLS for p in offered):
        return head, False
    if LEGACY_SUBPROTOCOL in offered:
        return _join(_set_header(lines, "Sec-WebSocket-Protocol", SDK_SUBPROTOCOLS[0])), True
    said = ", ".join(repr(printable(p, 60)) for p in offered[:8]) + (", ..." if len(offered) > 8 else "")
    raise BadRequest("400 Bad Request",
                     f"it offered the WebSocket subprotocols {said}" if offered else "it offered no WebSocket subprotocol",
                     f"no supported WebSocket subprotocol: this server speaks {', '.join(SUBPROTOCOLS)}\n",
                     kind="subprotocol")


def translate_response(head: bytes) -> bytes:
    """The SDK's handshake answer as a legacy client must see it: its own subprotocol name chosen."""
    lines = _lines(head)
    if _header_values(lines, "sec-websocket-protocol") == [SDK_SUBPROTOCOLS[0]]:
        return _join(_set_header(lines, "Sec-WebSocket-Protocol", LEGACY_SUBPROTOCOL))
    return head


def http_response(status: str, body: str) -> bytes:
    data = body.encode()
    return (f"HTTP/1.1 {status}\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: {len(data)}\r\n"
            f"Connection: close\r\n\r\n").encode() + data


class FrameGuard:
    """Follows the WebSocket frames a client sends (RFC 6455 5.2) by their headers alone and refuses a message
    larger than ``max_message`` bytes (a fragmented message counts all its fragments) before its payload arrives."""

    def __init__(self, max_message: int = MAX_MESSAGE):
        self.max_message = max_message
        self._skip = 0                 # payload bytes of the current frame still to pass
        self._head = bytearray()       # header bytes of the next frame so far
        self._message = 0              # bytes of the data message being assembled from fragments
        self.closed = False            # a close frame has passed

    @property
    def at_boundary(self) -> bool:
        """True between frames (a close frame may be inserted here)."""
        return not self._skip and not self._head

    def feed(self, data: bytes) -> str | None:
        """Account for ``data``; the reason to close the connection, or None."""
        i, n = 0, len(data)
        while i < n:
            if self._skip:
                k = min(self._skip, n - i)
                self._skip -= k
                i += k
                continue
            self._head.append(data[i])
            i += 1
            h = self._head
            if len(h) < 2:
                continue
            ext = {126: 2, 127: 8}.get(h[1] & 0x7F, 0)
            if len(h) < 2 + ext + (4 if h[1] & 0x80 else 0):
                continue
            length = int.from_bytes(h[2:2 + ext], "big") if ext else h[1] & 0x7F
            if h[0] & 0x0F == 8:
                self.closed = True
            elif h[0] & 0x0F < 8:      # data or continuation frame (control frames are <= 125 bytes by RFC)
                self._message += length
                if self._message > self.max_message:
                    return f"it sent a message of {self._message} bytes or more (the limit is {self.max_message})"
                if h[0] & 0x80:        # FIN: the message is complete
                    self._message = 0
            self._skip = length
            h.clear()
        return None


#: a masked close frame, status 1001 (going away): sent to the SDK for a client that vanished between frames
_CLOSE_GOING_AWAY = bytes([0x88, 0x82, 0, 0, 0, 0, 0x03, 0xE9])


async def _discard_until_eof(reader: asyncio.StreamReader) -> None:
    while await reader.read(65536):
        pass


class _Throttle:
    """At most one line per kind of event per ``period`` seconds; the lines held back are counted in the next one
    of that kind (a flood of one kind hides neither itself nor the others)."""

    def __init__(self, log: Callable[[str], None], period: float = LOG_PERIOD):
        self.log, self.period = log, period
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def __call__(self, kind: str, line: str) -> None:
        now = time.monotonic()
        if now - self._last.get(kind, -float("inf")) < self.period:
            self._held[kind] = self._held.get(kind, 0) + 1
            return
        self._last[kind] = now
        held = self._held.pop(kind, 0)
        self.log(line + (f" (and {held} more such lines in the last {self.period:g} s)" if held else ""))


class _Conn:
    """One client connection: its address, its side of the relay and, once relayed, the SDK's side."""

    __slots__ = ("who", "writer", "upstream", "since")

    def __init__(self, who: str, writer: asyncio.StreamWriter):
        self.who, self.writer, self.upstream, self.since = who, writer, None, time.monotonic()

    def abort(self) -> None:
        for w in (self.writer, self.upstream):
            if w is not None:
                w.transport.abort()


class Bridge:
    """Listens on ``(host, port)`` and relays each Foxglove client to the SDK's server on 127.0.0.1:``backend_port``.

    Binds in the constructor (raises OSError for a taken port or a bad host), then serves from a thread of its own
    until :meth:`close`. ``log`` receives one line per refused or dropped client (throttled)."""

    def __init__(self, host: str, port: int, backend_port: int, *, log: Callable[[str], None],
                 max_clients: int = MAX_CLIENTS, max_message: int = MAX_MESSAGE,
                 handshake_timeout: float = HANDSHAKE_TIMEOUT, release_memory: bool = True):
        self.backend_port = backend_port
        self.max_clients = max_clients
        self.max_message = max_message
        self.handshake_timeout = handshake_timeout
        self.release_memory = release_memory
        self._log = _Throttle(log)
        self.refused = 0                     # clients refused or dropped so far
        self.relayed = 0                     # connections relayed to the SDK so far
        self.trims = 0                       # times free memory was returned
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
        self._sock = socket.create_server((host, port), family=family, backlog=128)
        self.port = self._sock.getsockname()[1]
        self._pending: OrderedDict[_Conn, None] = OrderedDict()     # handshakes in progress, oldest first
        self._relays: set[_Conn] = set()
        self._tasks: set[asyncio.Task] = set()
        self._trim_handle = None
        self._loop = asyncio.new_event_loop()
        started = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(started,), name="flagbot-view-bridge", daemon=True)
        self._thread.start()
        started.wait()

    # ------------------------------------------------------------------------------------------ lifetime
    def _run(self, started: threading.Event) -> None:
        asyncio.set_event_loop(self._loop)
        self._server = self._loop.run_until_complete(
            asyncio.start_server(self._accept, sock=self._sock, limit=MAX_HEAD))
        started.set()
        try:
            self._loop.run_forever()
        finally:
            self._loop.close()

    def close(self) -> None:
        """Stop listening and drop every connection (idempotent)."""
        if not self._thread.is_alive():
            return

        async def shutdown():
            self._server.close()
            for conn in [*self._pending, *self._relays]:
                conn.abort()             # each task then ends by itself (a cancelled one would log a traceback)
            if self._tasks:
                await asyncio.wait(set(self._tasks), timeout=2.0)
            self._loop.stop()
        asyncio.run_coroutine_threadsafe(shutdown(), self._loop)
        self._thread.join(timeout=5.0)

    @property
    def connections(self) -> int:
        """Connections being relayed now."""
        return len(self._relays)

    @property
    def pending(self) -> int:
        """Connections whose request head is not complete yet."""
        return len(self._pending)

    # ------------------------------------------------------------------------------------------ serving
    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        conn = _Conn(f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else "?", writer)
        task = asyncio.current_task()
        self._tasks.add(task)
        try:
            if self._admit(conn):
                self._pending[conn] = None
                try:
                    head = await self._handshake(reader, conn)
                finally:
                    self._pending.pop(conn, None)
                if head is not None:
                    self._relays.add(conn)
                    try:
                        await self._relay(reader, conn, head)
                    finally:
                        self._relays.discard(conn)
                        self._departed()
        except (OSError, asyncio.IncompleteReadError, asyncio.CancelledError):
            pass                           # dropped (by the client, or aborted here): nothing more to do
        finally:
            writer.close()                 # after any answer queued for it
            self._tasks.discard(task)

    def _admit(self, conn: _Conn) -> bool:
        """Room for one more handshake? When :data:`MAX_PENDING` are pending, the oldest goes if it has had a
        second (a stalled or trickling request); a burst of new ones is not broken up, the newcomer waits instead."""
        if len(self._pending) < MAX_PENDING:
            return True
        oldest = next(iter(self._pending))
        if time.monotonic() - oldest.since >= 1.0:
            self._pending.pop(oldest)
            self._note("evicted", f"dropped a connection from {oldest.who}: its request was not complete after "
                       f"{time.monotonic() - oldest.since:.1f} s while {MAX_PENDING} others waited")
            oldest.abort()
            return True
        self._refuse(conn, "pending", http_response("503 Service Unavailable", "too many connections\n"),
                     f"refused a connection from {conn.who}: {MAX_PENDING} requests are pending")
        return False

    def _note(self, kind: str, reason: str) -> None:
        self.refused += 1
        self._log(kind, f"live view: {reason}")

    def _refuse(self, conn: _Conn, kind: str, answer: bytes | None, reason: str) -> None:
        self._note(kind, reason)
        if answer is not None:
            conn.writer.write(answer)
        conn.writer.close()

    async def _handshake(self, reader, conn: _Conn):
        """The request head to send the SDK and whether to rename the answer; None if refused."""
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), self.handshake_timeout)
        except asyncio.TimeoutError:
            self._refuse(conn, "timeout", None, f"dropped a connection from {conn.who}: no complete request within "
                                     f"{self.handshake_timeout:g} s")
            return None
        except asyncio.LimitOverrunError:
            self._refuse(conn, "head", http_response("431 Request Header Fields Too Large", "request head too large\n"),
                         f"refused a connection from {conn.who}: a request head over {MAX_HEAD} bytes")
            return None
        try:
            sdk_head, legacy = translate_request(head)
        except BadRequest as bad:
            self._refuse(conn, bad.kind, http_response(bad.status, bad.body),
                         f"refused a client from {conn.who}: {bad.reason}")
            return None
        if len(self._relays) >= self.max_clients:
            self._refuse(conn, "clients", http_response("503 Service Unavailable", "too many clients\n"),
                         f"refused a client from {conn.who}: {self.max_clients} clients are connected already")
            return None
        return sdk_head, legacy

    async def _relay(self, reader, conn: _Conn, head) -> None:
        sdk_head, legacy = head
        try:
            up_reader, conn.upstream = await asyncio.open_connection("127.0.0.1", self.backend_port, limit=MAX_HEAD)
        except OSError:
            self._refuse(conn, "relay", http_response("503 Service Unavailable", "the live view is stopping\n"),
                         f"could not relay {conn.who}: the server is not accepting connections")
            return
        self.relayed += 1
        guard = FrameGuard(self.max_message)
        try:
            conn.upstream.write(sdk_head)
            answer = await asyncio.wait_for(up_reader.readuntil(b"\r\n\r\n"), self.handshake_timeout)
            conn.writer.write(translate_response(answer) if legacy else answer)
            await conn.writer.drain()
            ended = await self._pump_both(reader, up_reader, conn, guard)
            if ended == "client":
                # the client has gone: close the SDK's side as a client would, so that it stops sending and ends
                # the connection itself (closed under it, it logs errors for the messages it was sending)
                if guard.at_boundary and not guard.closed:
                    conn.upstream.write(_CLOSE_GOING_AWAY)
                await asyncio.wait_for(_discard_until_eof(up_reader), self.handshake_timeout)
        except (asyncio.TimeoutError, asyncio.LimitOverrunError):
            pass
        finally:
            conn.upstream.close()

    async def _pump_both(self, reader, up_reader, conn: _Conn, guard: FrameGuard) -> str:
        """Copy both ways until one side ends; which: "client", "server" or "refused" (a message too large)."""
        async def copy(src, dst, check) -> str:
            try:
                while True:
                    data = await src.read(65536)
                    if not data:
                        return "eof"
                    why = check(data) if check is not None else None
                    if why:
                        self._note("message", f"closed the connection of {conn.who}: {why}")
                        return "refused"
                    dst.write(data)
                    await dst.drain()          # a slow reader holds the other side back: no buffer grows
            except OSError:
                return "eof"
        up = asyncio.ensure_future(copy(reader, conn.upstream, guard.feed))
        down = asyncio.ensure_future(copy(up_reader, conn.writer, None))
        try:
            await asyncio.wait({up, down}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in (up, down):
                t.cancel()
            await asyncio.gather(up, down, return_exceptions=True)
        if up.done() and not up.cancelled() and up.result() == "refused":
            conn.abort()
            return "refused"
        return "client" if up.done() and not up.cancelled() else "server"

    def _departed(self) -> None:
        """A relayed client left: once departures settle, return the memory its buffers held."""
        if not self.release_memory or _MALLOC_TRIM is None:
            return
        if self._trim_handle is not None:
            self._trim_handle.cancel()
        self._trim_handle = self._loop.call_later(TRIM_DELAY, self._trim)

    def _trim(self) -> None:
        self._trim_handle = None
        if release_free_memory():
            self.trims += 1
