"""Helpers for tests that talk to flagbot nodes running in other processes over real DDS (localhost only).

conftest.py has already set the loopback-only DDS environment (flagbot_sim/ros/dds.py on top of
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), a ROS_DOMAIN_ID of this test process and ROS_LOG_DIR; child processes
inherit them unchanged (the rclpy wheels need the parent's environment).
"""
from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

import rclpy
from rcl_interfaces.msg import Parameter as ParameterMsg
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from flagbot_sim.ros.dds import loopback_only

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: s to wait for a node to start and be discovered (its first message, its services): a first /clock came 36 s
#: after the start on a cold kernel cache beside ten busy processes. Generous: it costs time only when something is
#: really broken
DISCOVERY_TIMEOUT = 120.0
#: s to wait for something a running node does within a second or two on a quiet machine (the next diagnostic, a
#: command in force, a few more ticks): a loaded CI machine (2 cores at load 8) can stall a process for seconds.
#: Generous for the same reason
EVENT_TIMEOUT = 120.0
#: queue depth of the test's subscriptions: a starved test process must not drop what it counts or reads in order
#: (a subscription's KEEP_LAST queue overflows while its callbacks do not run)
DEPTH = 1000


def wall_ns() -> int:
    """Now on the clock DDS stamps a message's source_timestamp with (the system clock, shared by every process on
    this machine): take it after an event (a service answer) to select the messages published after it."""
    return time.time_ns()


class ChildProcess:
    """A child Python process (``python ARGV``) with its output in a temp file.

    stop() signals it and returns (exit code, output); wait() fails the test if it does not end in time."""

    def __init__(self, *argv: str, pipe: bool = False):
        """``pipe``: the output goes through a pipe instead of a file (for a child whose file writes are
        limited, e.g. by RLIMIT_FSIZE: a pipe is not a file)."""
        env = dict(os.environ)
        assert loopback_only(env), "conftest.py keeps DDS on this machine"
        assert env.get("ROS_DOMAIN_ID")
        env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
        self.log = None if pipe else tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen([sys.executable, *argv], env=env, stdout=subprocess.PIPE if pipe else self.log,
                                     stderr=subprocess.STDOUT, cwd=ROOT, text=pipe)
        self._lines: list[str] = []
        self._reader = None
        if pipe:
            self._reader = threading.Thread(target=lambda: self._lines.extend(self.proc.stdout), daemon=True)
            self._reader.start()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def output(self) -> str:
        if self.log is None:
            if self.proc.poll() is not None:
                self._reader.join(5.0)
            return "".join(self._lines)
        self.log.seek(0)
        return self.log.read()

    def wait(self, timeout: float = 60.0):
        try:
            return self.proc.wait(timeout=timeout), self.output()
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(f"process did not finish in {timeout} s:\n{self.output()}") from None

    def stop(self, sig=signal.SIGINT, timeout: float = 60.0):
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        return self.wait(timeout)

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


class NodeProcess(ChildProcess):
    """A node started as ``python -m MODULE ARGS``."""

    def __init__(self, module: str, *args: str):
        super().__init__("-m", module, *args)


def t_of(stamp):
    return stamp.sec + 1e-9 * stamp.nanosec


class Listener:
    """Collects everything sim_node publishes, and asserts nothing non-finite ever arrives.

    ``msgs[key]`` holds the messages in arrival order, ``sent[key]`` beside it each one's source timestamp (wall
    time in ns at the publish call, taken by the publisher's DDS): after an event, select what was published after
    it with :meth:`after` (a message published before the event can still be waiting in the queue when the test
    sees the event's answer), and the unstamped Float64 streams by the /clock published before them with
    :meth:`since_clock`.

    Lives on the module's shared probe node: close() it at the end of the test, or later tests keep receiving
    (and decoding) messages into it."""

    KEYS = ("clock", "pose", "odom", "joints", "omega_h", "omega_t", "speed", "markers", "diag")

    def __init__(self, node: Node):
        self.node = node
        self.msgs = {k: [] for k in self.KEYS}
        self.sent = {k: [] for k in self.KEYS}
        self.non_finite = []
        sub = node.create_subscription
        self.subs = [
            sub(Clock, "/clock", self._cb("clock"), DEPTH),
            sub(PoseStamped, "head_pose", self._cb("pose"), DEPTH),
            sub(Odometry, "odom", self._cb("odom"), DEPTH),
            sub(JointState, "joint_states", self._cb("joints"), DEPTH),
            sub(Float64, "omega_h", self._cb("omega_h"), DEPTH),
            sub(Float64, "omega_t", self._cb("omega_t"), DEPTH),
            sub(Float64, "speed", self._cb("speed"), DEPTH),
            sub(MarkerArray, "markers", self._cb("markers"), DEPTH),
            sub(DiagnosticArray, "/diagnostics", self._cb("diag"), DEPTH),
        ]
        self.cmd = node.create_publisher(Float64, "cmd_omega", 10)
        # the node's own services (~/pause): /sim_node/pause
        self.pause = node.create_client(SetBool, "/sim_node/pause")
        self.reset = node.create_client(Trigger, "/sim_node/reset")

    def close(self) -> None:
        """Destroy the subscriptions, the publisher and the clients on the shared node (idempotent)."""
        for s in self.subs:
            self.node.destroy_subscription(s)
        self.subs = []
        if self.cmd is not None:
            self.node.destroy_publisher(self.cmd)
            self.node.destroy_client(self.pause)
            self.node.destroy_client(self.reset)
            self.cmd = self.pause = self.reset = None

    def _cb(self, key):
        def cb(m, info):
            self.msgs[key].append(m)
            self.sent[key].append(info["source_timestamp"])
            for x in _floats(m):
                if not math.isfinite(x):
                    self.non_finite.append((key, x))
        return cb

    @property
    def clock(self) -> float:
        return t_of(self.msgs["clock"][-1].clock) if self.msgs["clock"] else 0.0

    @staticmethod
    def diag_values_of(msg) -> dict:
        s = msg.status[0]
        return {kv.key: kv.value for kv in s.values} | {"_level": s.level, "_message": s.message}

    def diag_values(self) -> dict:
        return self.diag_values_of(self.msgs["diag"][-1])

    def after(self, key: str, t_wall_ns: int) -> list:
        """The messages on ``key`` published at or after wall time ``t_wall_ns`` (see :func:`wall_ns`), in order."""
        return [m for m, s in zip(self.msgs[key], self.sent[key]) if s >= t_wall_ns]

    def clock_published(self, t: float) -> int | None:
        """Source timestamp of the first /clock received that reads ``t`` or later (None before one came)."""
        for m, s in zip(self.msgs["clock"], self.sent["clock"]):
            if t_of(m.clock) >= t:
                return s
        return None

    def since_clock(self, key: str, t: float) -> list:
        """The messages on ``key`` published after the first /clock reading ``t`` or later: a tick publishes its
        clock first, so these carry the state of simulated time ``t`` or later (for the unstamped streams, e.g.
        ``speed``; a later message on another topic says nothing about which tick the last one came from)."""
        s = self.clock_published(t)
        return [] if s is None else self.after(key, s)

    #: the streams sim_node publishes with /clock in every tick, stamped alike
    TICK_STREAMS = ("pose", "odom", "joints")
    #: the streams it publishes after them in every tick, unstamped
    UNSTAMPED_STREAMS = ("omega_h", "omega_t", "speed")

    def run_until(self, t: float, timeout: float = DISCOVERY_TIMEOUT + EVENT_TIMEOUT) -> None:
        """Spin until /clock reads ``t`` and every per-tick stream has caught up with it too.
        The clock message of a tick is published first: on a loaded machine the listener may take it while the
        same tick's (and earlier ticks') other messages still wait in their queues, so a test that read them
        after a bare clock wait would find a gap (CI did, at load 8: no joint states in [4.6, 23.4] s). The stamped
        streams have caught up when their last header stamp reads ``t``, the unstamped ones when their last
        message was published after the first /clock that read ``t``. A stream with nothing received yet has not
        (each topic is matched on its own: the first /clock can come while another topic is not matched yet)."""
        def caught_up():
            if self.clock < t:
                return False
            if not all(self.msgs[k] and t_of(self.msgs[k][-1].header.stamp) >= t for k in self.TICK_STREAMS):
                return False
            s = self.clock_published(t)
            return all(self.msgs[k] and self.sent[k][-1] >= s for k in self.UNSTAMPED_STREAMS)
        spin_until(self.node, caught_up, timeout,
                   f"simulation time {t} s on /clock and {', '.join(self.TICK_STREAMS + self.UNSTAMPED_STREAMS)}")


def _floats(m):
    if isinstance(m, float):
        yield m
    elif isinstance(m, (list, tuple)) or type(m).__name__ == "array":
        for x in m:
            yield from _floats(x)
    elif hasattr(m, "get_fields_and_field_types"):
        for f in m.get_fields_and_field_types():
            yield from _floats(getattr(m, f))


def spin_until(node: Node, predicate, timeout: float, what: str = "condition") -> None:
    t0 = time.monotonic()
    while not predicate():
        rclpy.spin_once(node, timeout_sec=0.05)
        if time.monotonic() - t0 > timeout:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def call(node: Node, client, request, timeout: float = EVENT_TIMEOUT):
    spin_until(node, client.service_is_ready, DISCOVERY_TIMEOUT, f"service {client.srv_name}")
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    assert future.done(), f"no answer from {client.srv_name}"
    return future.result()


def set_params(node: Node, target: str, **values):
    """Set parameters of another node; returns the list of SetParametersResult."""
    cli = node.create_client(SetParameters, f"/{target}/set_parameters")
    req = SetParameters.Request()
    req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
    try:
        return call(node, cli, req).results
    finally:
        node.destroy_client(cli)


def get_params(node: Node, target: str, names: list[str]) -> dict:
    cli = node.create_client(GetParameters, f"/{target}/get_parameters")
    try:
        res = call(node, cli, GetParameters.Request(names=names))
    finally:
        node.destroy_client(cli)
    return {n: Parameter.from_parameter_msg(ParameterMsg(name=n, value=v)).value for n, v in zip(names, res.values)}


def describe_all_params(node: Node, target: str) -> dict:
    lst = node.create_client(ListParameters, f"/{target}/list_parameters")
    desc = node.create_client(DescribeParameters, f"/{target}/describe_parameters")
    try:
        names = list(call(node, lst, ListParameters.Request()).result.names)
        ds = call(node, desc, DescribeParameters.Request(names=names)).descriptors
    finally:
        node.destroy_client(lst)
        node.destroy_client(desc)
    return {d.name: d for d in ds}


def _address(hex_addr: str, v6: bool) -> tuple[str, int]:
    ip, port = hex_addr.split(":")
    raw = bytes.fromhex(ip)
    if v6:      # four host-order 32-bit words
        return socket.inet_ntop(socket.AF_INET6, b"".join(raw[i:i + 4][::-1] for i in range(0, 16, 4))), int(port, 16)
    return socket.inet_ntop(socket.AF_INET, raw[::-1]), int(port, 16)


def inet_sockets(pid: int | str = "self") -> list[tuple[str, str, int]]:
    """(protocol, local address, port) of every UDP/TCP socket process ``pid`` holds: its /proc/PID/fd socket
    inodes matched in /proc/PID/net/{udp,udp6,tcp,tcp6}."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:         # closed meanwhile
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out = []
    for proto in ("udp", "udp6", "tcp", "tcp6"):
        with open(f"/proc/{pid}/net/{proto}") as f:
            for line in f.read().splitlines()[1:]:
                fields = line.split()
                if fields[9] in inodes:
                    out.append((proto, *_address(fields[1], proto.endswith("6"))))
    return out


def is_loopback(address: str) -> bool:
    """127.0.0.0/8, ::1 or an IPv4-mapped 127.x; the wildcard 0.0.0.0 / :: is NOT loopback (every interface)."""
    return address.startswith("127.") or address == "::1" or address.startswith("::ffff:127.")
