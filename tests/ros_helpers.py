"""Helpers for tests that talk to flagbot nodes running in other processes over real DDS (localhost only).

conftest.py has already set the loopback-only DDS environment (flagbot_sim/ros/dds.py on top of
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), a ROS_DOMAIN_ID of this test process and ROS_LOG_DIR; child processes
inherit them unchanged (the rclpy wheels need the parent's environment).
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time

import rclpy
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter

from flagbot_sim.ros.dds import loopback_only

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DISCOVERY_TIMEOUT = 20.0


class ChildProcess:
    """A child Python process (``python ARGV``) with its output in a temp file.

    stop() signals it and returns (exit code, output); wait() fails the test if it does not end in time."""

    def __init__(self, *argv: str):
        env = dict(os.environ)
        assert loopback_only(env), "conftest.py keeps DDS on this machine"
        assert env.get("ROS_DOMAIN_ID")
        env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
        self.log = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen([sys.executable, *argv], env=env, stdout=self.log, stderr=subprocess.STDOUT,
                                     cwd=ROOT)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def output(self) -> str:
        self.log.seek(0)
        return self.log.read()

    def wait(self, timeout: float = 60.0):
        try:
            return self.proc.wait(timeout=timeout), self.output()
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise AssertionError(f"process did not finish in {timeout} s:\n{self.output()}") from None

    def stop(self, sig=signal.SIGINT, timeout: float = 20.0):
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


def spin_until(node: Node, predicate, timeout: float, what: str = "condition") -> None:
    t0 = time.monotonic()
    while not predicate():
        rclpy.spin_once(node, timeout_sec=0.05)
        if time.monotonic() - t0 > timeout:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def call(node: Node, client, request, timeout: float = 10.0):
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
