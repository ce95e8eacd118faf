"""LiveView: a Foxglove WebSocket server showing the robot live (the ``[view]`` extra, foxglove-sdk).

Connect the Foxglove app or Lichtblick (Open connection -> Foxglove WebSocket -> ``ws://127.0.0.1:PORT``) and import
the layout :data:`LAYOUT_FILE` (Layouts -> Import from file) to see the robot in 3-D and its rates in plots
(docs/live_view.md). Every name of the protocol is served (``foxglove.websocket.v1``, which Lichtblick and the npm
client offer, and the SDK's ``foxglove.sdk.v1`` / ``v1.1``): clients reach the SDK's server through
:class:`~.bridge.Bridge`, which also keeps hostile clients out and returns a departed client's memory. Channels:

=================  ========================  ===========================================================
topic              schema                    content
=================  ========================  ===========================================================
``/flagbot/scene`` foxglove.SceneUpdate      head, plate, flagella (true radii), frame ``world``
``/flagbot/tube``  foxglove.SceneUpdate      the experiments' container tube (context: the sim has no wall)
``/tf``            foxglove.FrameTransforms  world -> head
``/flagbot/state`` JSON (flagbot_sim.State)  t, omega_T, omega_h, omega_t, v, motor_torque, ... (SI units)
=================  ========================  ===========================================================

The server advertises the ``time`` capability and broadcasts the simulated time before each update, so the app's
clock (and the plots' time axis) is simulation time, as with ``use_sim_time``. Messages carry it as log time too.

Cost (``benchmarks/live_view_cost.py`` prints it; measured here, 2 shared cores): :meth:`LiveView.update` returns
after one clock read (~0.15 us) when called sooner than ``1 / max_rate`` after its last publication, and after
four channel checks (~0.6 us, no geometry built) when no client is subscribed; a publication (snapshot, geometry,
~40 primitives, four messages) takes ~0.3-0.7 ms for n = 2-3, i.e. at 30 Hz about 1-2 % of one core. Thread
safety: every method may be called from any thread; publications are serialised by a lock, and the server runs
in the SDK's own threads. ``update(sim)`` reads ``sim``'s state, so call it from the thread that steps the
simulation (or while holding whatever lock guards it).
"""
from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Callable

from ..cliutil import dumps
from ..optional import require
from .args import DEFAULT_PORT
from .bridge import MAX_CLIENTS, Bridge
from .geometry import RobotGeometry

#: the Foxglove layout shipped with the package (also installed to share/flagbot_sim/foxglove/)
LAYOUT_FILE = Path(__file__).with_name("flagbot.foxglove-layout.json")

TOPIC_SCENE = "/flagbot/scene"
TOPIC_TUBE = "/flagbot/tube"
TOPIC_TF = "/tf"
TOPIC_STATE = "/flagbot/state"
TOPICS = (TOPIC_SCENE, TOPIC_TUBE, TOPIC_TF, TOPIC_STATE)

#: the tube is re-sent this often (s of wall time): a client that reconnects gets it again without asking
TUBE_PERIOD = 1.0


def _to_stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class ViewError(RuntimeError):
    """The live view cannot start (port taken, bad host, ...); the message names the address."""


class LiveView:
    """A Foxglove WebSocket server for one robot.

    :param host: interface to bind; ``127.0.0.1`` (this machine only) unless the user asks for another.
    :param port: TCP port; 0 picks a free one (read it back from :attr:`port`).
    :param max_rate: most publications per second of wall time (:meth:`update` skips calls in between).
    :param frame: the fixed frame's name; ``child_frame`` the head's.
    :param tube: also show the experiments' container tube (:func:`scene_msgs.tube_update`).
    :param log: receives one line per refused or dropped client (what it offered, which limit); default stderr.
    :param max_clients: most clients served at once (503 beyond).
    :param release_memory: return the memory a client's buffers held to the system after it leaves (glibc).

    Clients connect to :class:`~.bridge.Bridge` on ``host:port``, which accepts every name of the protocol
    (``foxglove.websocket.v1``, ``foxglove.sdk.v1``, ``foxglove.sdk.v1.1``) and relays to the SDK's server on a
    loopback port of its own.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *, max_rate: float = 30.0,
                 frame: str = "world", child_frame: str = "head", tube: bool = True, name: str = "flagbot_sim",
                 log: Callable[[str], None] | None = None, max_clients: int = MAX_CLIENTS,
                 release_memory: bool = True):
        foxglove = require("view", "the Foxglove live view")
        from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
        from foxglove.websocket import Capability, ServerListener

        from . import scene_msgs
        if not (max_rate > 0):
            raise ValueError(f"max_rate must be > 0 publications per second, got {max_rate!r}")
        if not (isinstance(port, int) and 0 <= port <= 65535):
            raise ViewError(f"live view port must be an integer 0-65535, got {port!r}")
        self._msgs = scene_msgs
        self.host = host
        self.frame = frame
        self.child_frame = child_frame
        self.min_interval = 1.0 / float(max_rate)
        self.tube = tube
        self._lock = threading.Lock()
        self._last = -float("inf")           # monotonic time of the last publication
        self._last_tube = -float("inf")
        self._fresh_subscriber = False       # set by the server thread: publish at the next update, rate or not
        self._closed = False
        self.published = 0                   # publications so far
        self._ctx = foxglove.Context()
        self._scene = SceneUpdateChannel(TOPIC_SCENE, context=self._ctx)
        self._tube = SceneUpdateChannel(TOPIC_TUBE, context=self._ctx)
        self._tf = FrameTransformsChannel(TOPIC_TF, context=self._ctx)
        self._state = foxglove.Channel(TOPIC_STATE, schema=foxglove.Schema(
            name="flagbot_sim.State", encoding="jsonschema", data=dumps(scene_msgs.STATE_SCHEMA).encode()),
            message_encoding="json", context=self._ctx)
        self._channels = (self._scene, self._tube, self._tf, self._state)
        view = self

        class _Listener(ServerListener):       # the Protocol's methods are the no-op defaults
            def on_subscribe(self, client, channel) -> None:
                view._fresh_subscriber = True

        self._server = None
        try:
            # the SDK's server on a loopback port of its own; clients reach it through the bridge (see .bridge)
            self._server = foxglove.start_server(name=name, host="127.0.0.1", port=0, context=self._ctx,
                                                 capabilities=[Capability.Time], server_listener=_Listener())
            self.bridge = Bridge(host, port, int(self._server.port), log=log or _to_stderr,
                                 max_clients=max_clients, release_memory=release_memory)
        except Exception as exc:     # OSError (address in use, bad host), or the SDK's own error types
            if self._server is not None:
                self._server.stop()
            for ch in self._channels:
                ch.close()
            raise ViewError(f"cannot serve the live view on {host}:{port}: {exc}") from None
        self.port = self.bridge.port

    # ------------------------------------------------------------------------------------------ state
    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def has_clients(self) -> bool:
        """Whether any client is subscribed to any channel."""
        return not self._closed and any(ch.has_sinks() for ch in self._channels)

    # ------------------------------------------------------------------------------------------ publishing
    def update(self, sim, snapshot=None, *, force: bool = False) -> bool:
        """Publish ``sim``'s robot now if due (``max_rate``) and watched; True if published.

        ``snapshot``: ``sim.snapshot()`` if the caller already has it (saves recomputing it). ``force``: ignore the
        rate limit (still nothing is built without a subscriber)."""
        if not self._due(force):
            return False
        if not self.has_clients():
            return False
        return self.publish(RobotGeometry.from_simulation(sim, snapshot), force=True)

    def publish(self, geom: RobotGeometry, *, force: bool = False) -> bool:
        """Publish a ready :class:`RobotGeometry` (a recording's, a simulation's) under the same rules as
        :meth:`update`: True if sent to a subscribed client. Nothing non-finite is published: such a geometry is
        skipped (False)."""
        msgs = self._msgs
        with self._lock:
            if self._closed or not (force or self._due(False)) or not self.has_clients():
                return False
            now = time.monotonic()
            self._last = now
            self._fresh_subscriber = False
            if not msgs.is_finite(geom):
                return False
            t_ns = max(0, int(round(geom.t * 1e9)))
            self._server.broadcast_time(t_ns)
            if self.tube and now - self._last_tube >= TUBE_PERIOD:
                self._tube.log(msgs.tube_update(geom.t, self.frame), log_time=t_ns)
                self._last_tube = now
            self._scene.log(msgs.scene_update(geom, self.frame), log_time=t_ns)
            tf = msgs.frame_transforms(geom, self.frame, self.child_frame)
            if tf is not None:
                self._tf.log(tf, log_time=t_ns)
            if geom.values:
                self._state.log(msgs.state_message(geom.values), log_time=t_ns)
            self.published += 1
            return True

    def _due(self, force: bool) -> bool:
        if force or self._fresh_subscriber:
            if self._fresh_subscriber:
                self._last_tube = -float("inf")      # a new subscriber gets the tube at once too
            return True
        return time.monotonic() - self._last >= self.min_interval

    # ------------------------------------------------------------------------------------------ lifetime
    def close(self, linger: float = 0.25) -> None:
        """Stop the server and close the channels (idempotent). With a client subscribed, first wait ``linger``
        seconds: the SDK sends from its own threads, and stopping at once can drop the last messages queued."""
        if linger > 0 and self.has_clients():
            time.sleep(linger)
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self.bridge.close()
                self._server.stop()
            finally:
                for ch in self._channels:
                    ch.close()

    def __enter__(self) -> "LiveView":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
