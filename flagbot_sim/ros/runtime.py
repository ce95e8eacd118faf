"""Process entry helpers: init, spin, and a clean shutdown on SIGINT/SIGTERM (no traceback, no crash).

rclpy's own signal handler shuts every context down from a separate thread, while the main thread may be
inside a callback that is publishing; under load that race crashed sim_node with SIGSEGV inside the middleware
(seen once in ~70 signal-shutdown runs). So processes here take the signals themselves: the handler only
raises a flag, the spin loop notices it within one wait slice and tears down in order on the main thread.
A second signal falls through to the default action, so a hung teardown can still be interrupted.

Before rclpy.init, :func:`flagbot_sim.ros.dds.configure_dds` keeps DDS on the loopback interface unless the user
opted in (see that module).
"""
from __future__ import annotations

import contextlib
import re
import signal
import sys
import threading
import time
from typing import Callable, Iterator

import rclpy
from rclpy.callback_groups import CallbackGroup
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args

from ..cliutil import fast_exit
from .dds import configure_dds

SLICE = 0.1     # s: longest wait before a stop request is noticed


class StopRequest:
    """A stop flag set by SIGINT/SIGTERM or by any thread, with the ``threading.Event`` interface.

    The signal handler only assigns an attribute: it runs on the main thread between two bytecodes, possibly
    while that thread holds a lock (an Event's included), so it must not take one.
    """

    def __init__(self) -> None:
        self._signalled = False
        self._event = threading.Event()
        self._saved: dict[int, object] = {}
        self.raising = False          # inside :func:`interruptible`: a signal also raises KeyboardInterrupt

    def set(self) -> None:
        self._event.set()

    def is_set(self) -> bool:
        return self._signalled or self._event.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        end = None if timeout is None else time.monotonic() + timeout
        while not self.is_set():
            left = SLICE if end is None else min(SLICE, end - time.monotonic())
            if left <= 0:
                break
            self._event.wait(left)
        return self.is_set()

    def _on_signal(self, signum, frame) -> None:
        self._signalled = True
        for sig in self._saved:       # a second signal: the default action (KeyboardInterrupt / terminate)
            signal.signal(sig, signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL)
        if self.raising:
            raise KeyboardInterrupt

    def install(self) -> None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._saved[sig] = signal.signal(sig, self._on_signal)

    def uninstall(self) -> None:
        for sig, handler in self._saved.items():
            signal.signal(sig, handler)
        self._saved.clear()


class Polled(CallbackGroup):
    """A callback group the executor never runs: its subscriptions are left out of every wait set, and their
    owner takes the messages itself (:func:`take_all`) when it wants them.

    Why: for each message of a subscription it waits on, rclpy's executor rebuilds its wait set from every
    entity of the node, wakes, takes, deserialises and calls back in Python, on the thread that also runs the
    node's timers. For a topic where only the newest message matters (a motor command read once per step), a
    flood of messages then costs the timer its time; taken in the timer from a depth-1 queue, the cost per
    tick is one take, whatever the message rate.
    """

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        pass


def take_all(subscription, limit: int) -> list:
    """The messages waiting in ``subscription``'s queue, oldest first, at most ``limit`` (a subscription in a
    :class:`Polled` group; its QoS depth bounds how many can wait)."""
    out = []
    with subscription.handle:
        for _ in range(limit):
            taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
            if taken is None:
                break
            out.append(taken[0])
    return out


def release(executor: SingleThreadedExecutor | None, node) -> None:
    """Detach the node, stop the executor, destroy the node: in that order, whichever of them exist."""
    if executor is not None:
        if node is not None:
            executor.remove_node(node)
        executor.shutdown()
    if node is not None:
        node.destroy_node()


_ACTIVE: StopRequest | None = None


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """A long computation on the main thread that a stop request must cut short, not wait for (the first
    compile of the kernels, tens of seconds on a loaded machine): inside, SIGINT/SIGTERM raise KeyboardInterrupt
    as well as setting the stop flag. Only around work that holds nothing to close when it is cut."""
    stop = _ACTIVE
    if stop is None:
        yield
        return
    stop.raising = True
    try:
        yield
    finally:
        stop.raising = False


@contextlib.contextmanager
def ros_process(args: list[str] | None) -> Iterator[StopRequest]:
    """rclpy initialised without its signal handlers; SIGINT/SIGTERM set the yielded StopRequest.

    The body tears its own nodes down; the context is shut down on exit.
    """
    global _ACTIVE
    stop = StopRequest()
    configure_dds()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop.install()
    _ACTIVE = stop
    try:
        yield stop
    finally:
        _ACTIVE = None
        stop.uninstall()
        rclpy.try_shutdown()


class RosArgsError(ValueError):
    """The ``--ros-args`` section cannot be parsed (e.g. ``-p scene:=`` with no value)."""


def _rcl_message(exc: Exception) -> str:
    # rcl appends the C source location of every layer (", at /project/src/rcl/arguments.c:352"): not for users
    from ..values import one_line         # (beside the value checks; imported here only when there is an error)
    return one_line(re.sub(r",? at /\S+:\d+", "", str(exc)))


def user_args(argv: list[str]) -> list[str]:
    """The program's own arguments: ``argv`` without argv[0] and without its ``--ros-args ... [--]`` sections.

    Raises RosArgsError (one line) when the ROS arguments cannot be parsed."""
    try:
        return remove_ros_args(argv)[1:]
    except Exception as exc:  # noqa: BLE001 - rclpy raises its own RCL error types here
        raise RosArgsError(_rcl_message(exc)) from None


def wants_help(argv: list[str]) -> bool:
    """-h/--help among the program's own arguments (not a ROS argument); False if the ROS arguments are invalid
    (run_node then reports them)."""
    try:
        user = user_args(argv)
    except RosArgsError:
        return False
    return "-h" in user or "--help" in user


def run_node(make_node: Callable[[], object], argv: list[str] | None = None, *, process_exit: bool = False) -> int:
    """Create the node, spin it until SIGINT/SIGTERM or rclpy shutdown, then tear everything down in order.

    Exit code: 2 when the node cannot start (one line on stderr, no traceback), else what the node's ``close()``
    returns (an int; e.g. sim_node says 1 when a recording failed to write), else 0.

    ``process_exit``: the process ends when this returns (a node's console script), so once everything is torn
    down the interpreter's final garbage collection is skipped (:func:`flagbot_sim.cliutil.fast_exit`). Measured
    on sim_node after SIGINT: the teardown in order takes ~15 ms (60 ms closing a recording), the collection walk
    0.35-0.5 s of CPU; exit went from 0.5-1.2 s to 0.17-0.25 s on a loaded 2-core host.
    """
    try:
        return _run_node(make_node, sys.argv if argv is None else argv)
    finally:
        if process_exit:
            fast_exit()


def _run_node(make_node: Callable[[], object], argv: list[str]) -> int:
    code = 0
    try:
        user_args(argv)
    except RosArgsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        with ros_process(argv) as stop:
            node = None
            executor = SingleThreadedExecutor()
            try:
                node = make_node()
                executor.add_node(node)
                while not stop.is_set() and rclpy.ok():
                    executor.spin_once(timeout_sec=SLICE)
            except (KeyboardInterrupt, ExternalShutdownException):
                pass
            except Exception as exc:
                # a node that shut the context down from a callback (cmd_profile --exit-at-end) ends the loop
                # normally; anything else (a bad parameter, a bad scene at startup) is one line, not a traceback
                if rclpy.ok():
                    from ..values import one_line
                    print(f"error: {one_line(str(exc) or type(exc).__name__)}", file=sys.stderr)
                    code = 2
            finally:
                close = getattr(node, "close", None)
                if close is not None:
                    status = close()
                    if isinstance(status, int) and status and not code:
                        code = status
                release(executor, node)
    except Exception as exc:  # noqa: BLE001 - rclpy.init failed (ROS_DOMAIN_ID=abc), or the teardown did: one line
        print(f"error: {_rcl_message(exc) or type(exc).__name__}", file=sys.stderr)
        return 2
    return code
