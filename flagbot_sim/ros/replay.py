"""Replay: republish a recording with its recorded timing, and publish /clock from it.

The serialized bytes are republished unchanged (header stamps stay as recorded). Message *i* goes out at
``wall_start + (log_time_i - bag_start - offset) / rate``. ``/clock``: if the recording has /clock and it is not
excluded, the recorded clock messages are republished like any topic; otherwise a clock derived from the log time
of the playback position is published at ``clock_rate`` Hz, so ``use_sim_time`` nodes follow the recording either
way (``--no-clock`` turns the derived one off). With ``loop`` the clock jumps back at each restart, as in rosbag2.

/tf and /tf_static (tf2_msgs/msg/TFMessage, which every recording carries) are republished where tf2_msgs is
installed; elsewhere the replay says once that it skips them, and replays the rest.

Damaged files: everything readable is replayed; what was lost (bytes, log-time ranges, message counts when the
summary survived) is logged before playback starts and returned in :class:`ReplayStats`. A non-MCAP file raises
:class:`flagbot_sim.bag.NotMcapError` before any ROS entity is created.
"""
from __future__ import annotations

import argparse
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import rclpy
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..bag import BagError, BagReader, ScanReport, normalize_type
from ..bag.tf import TF_MESSAGE
from ..topics import CLOCK
from .recorder import message_class
from .runtime import SLICE, release, ros_process
from .tf_derive import NO_TF2, tf_message_class


@dataclass
class ReplayStats:
    published: dict[str, int] = field(default_factory=dict)
    clock_messages: int = 0
    loops: int = 0
    wall_seconds: float = 0.0
    max_lateness: float = 0.0        # s, worst delay of a publish behind its scheduled time
    skipped_topics: dict[str, str] = field(default_factory=dict)   # topic -> reason
    report: ScanReport | None = None
    interrupted: bool = False

    @property
    def total(self) -> int:
        return sum(self.published.values())

    def format(self) -> str:
        lines = [f"replayed {self.total} messages on {len(self.published)} topics in {self.wall_seconds:.2f} s "
                 f"({self.loops} pass{'es' if self.loops != 1 else ''}), {self.clock_messages} derived /clock "
                 f"messages, worst lateness {1e3 * self.max_lateness:.1f} ms"
                 + (" (interrupted)" if self.interrupted else "")]
        for t, n in sorted(self.published.items()):
            lines.append(f"  {t:32s} {n:8d}")
        for t, why in sorted(self.skipped_topics.items()):
            lines.append(f"  {t:32s} skipped: {why}")
        if self.report is not None and not self.report.ok:
            lines.append("  LOST: " + self.report.describe_loss())
        return "\n".join(lines)


def _matches(topic: str, patterns: Iterable[str]) -> bool:
    return any(topic == p or re.fullmatch(p, topic) for p in patterns)


def publisher_qos(offered) -> QoSProfile:
    """Offer what the recorded publishers offered: latched (TRANSIENT_LOCAL) if they all were, best effort if
    they all were; a deep KEEP_LAST queue so a burst is not dropped."""
    latched = bool(offered) and all(q.durability == "transient_local" for q in offered)
    best_effort = bool(offered) and all(q.reliability == "best_effort" for q in offered)
    depth = max([q.depth for q in offered if q.depth > 0] or [10])
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth if latched else max(depth, 100),
                      reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class Replayer:
    """Republish a recording through ``node``'s publishers. :meth:`run` blocks (call it from any thread).

    :param topics: include patterns (exact names or regular expressions); None = every recorded topic.
    :param exclude: patterns of topics not to replay.
    :param start_offset: seconds after the first message where playback starts.
    :param clock: publish /clock derived from log time when the recording has no (included) /clock.
    """

    def __init__(self, node: Node, path: str | Path, *, rate: float = 1.0, loop: bool = False,
                 topics: Iterable[str] | None = None, exclude: Iterable[str] = (), start_offset: float = 0.0,
                 clock: bool = True, clock_rate: float = 100.0):
        if not rate > 0:
            raise BagError(f"rate must be > 0, got {rate}")
        if not clock_rate > 0:
            raise BagError(f"clock rate must be > 0, got {clock_rate}")
        self.reader = BagReader(path)
        self.report = self.reader.report
        if self.report.messages == 0:
            raise BagError(f"{path}: no readable message" + (f" ({self.report.describe_loss()})"
                                                            if not self.report.ok else ""))
        if not 0 <= start_offset < max(self.report.duration, 1e-9):
            raise BagError(f"start offset {start_offset} s is outside the recording "
                           f"(0 to {self.report.duration:.3f} s)")
        self.node = node
        self.rate = rate
        self.loop = loop
        self.start_offset = start_offset
        self.clock_rate = clock_rate
        self.stats = ReplayStats(report=self.report)
        self.publishers = {}
        no_tf = []          # TFMessage topics where tf2_msgs is missing: said once for all of them
        for topic, info in sorted(self.report.topics.items()):
            if topics is not None and not _matches(topic, topics):
                continue
            if _matches(topic, exclude):
                continue
            if info.count == 0:
                continue
            if normalize_type(info.type_name) == TF_MESSAGE and tf_message_class() is None:
                no_tf.append(topic)
                self.stats.skipped_topics[topic] = NO_TF2
                continue
            try:
                cls = message_class(info.type_name)
            except BagError as exc:
                self.stats.skipped_topics[topic] = str(exc)
                node.get_logger().warning(f"not replaying {topic}: {exc}")
                continue
            self.publishers[topic] = node.create_publisher(cls, topic, publisher_qos(info.offered_qos))
        if no_tf:
            node.get_logger().warning(f"not replaying {' and '.join(no_tf)}: {NO_TF2}")
        self.clock_pub = None
        if clock and CLOCK not in self.publishers:
            from rosgraph_msgs.msg import Clock
            self._clock_cls = Clock
            self.clock_pub = node.create_publisher(Clock, CLOCK, QoSProfile(depth=10))
        if not self.report.ok:
            node.get_logger().warning(self.report.describe_loss() + " Replaying what could be read.")

    def wait_for_subscribers(self, timeout: float, stop: threading.Event | None = None) -> bool:
        """Wait until every replayed topic has a subscriber (or ``timeout`` s); graph discovery takes 0.1-3 s."""
        end = time.monotonic() + timeout
        while time.monotonic() < end and not (stop and stop.is_set()):
            if all(p.get_subscription_count() > 0 for p in self.publishers.values()):
                return True
            time.sleep(0.02)
        return all(p.get_subscription_count() > 0 for p in self.publishers.values())

    def _publish_clock(self, bag_ns: int) -> None:
        msg = self._clock_cls()
        msg.clock.sec, msg.clock.nanosec = divmod(int(bag_ns), 1_000_000_000)
        self.clock_pub.publish(msg)
        self.stats.clock_messages += 1

    def _sleep_until(self, t: float, stop: threading.Event) -> bool:
        """Sleep until monotonic time ``t``; False if stopped."""
        while True:
            dt = t - time.monotonic()
            if stop.is_set() or not rclpy.ok(context=self.node.context):
                return False
            if dt <= 0:
                return True
            stop.wait(min(dt, 0.1))

    def run(self, stop: threading.Event | None = None) -> ReplayStats:
        stop = stop or threading.Event()
        t_begin = time.monotonic()
        bag0 = self.report.start_ns + int(self.start_offset * 1e9)
        tick = 1.0 / self.clock_rate
        try:
            while True:
                self.stats.loops += 1
                wall0 = time.monotonic()
                next_clock = wall0
                for m in self.reader.messages(list(self.publishers), start_ns=bag0):
                    due = wall0 + (m.log_time_ns - bag0) * 1e-9 / self.rate
                    while self.clock_pub is not None and next_clock <= due:
                        if not self._sleep_until(next_clock, stop):
                            raise _Stopped
                        self._publish_clock(bag0 + (next_clock - wall0) * self.rate * 1e9)
                        next_clock += tick
                    if not self._sleep_until(due, stop):
                        raise _Stopped
                    self.publishers[m.topic].publish(m.data)
                    self.stats.max_lateness = max(self.stats.max_lateness, time.monotonic() - due)
                    self.stats.published[m.topic] = self.stats.published.get(m.topic, 0) + 1
                if not self.loop:
                    break
        except _Stopped:
            self.stats.interrupted = True
        except Exception:  # publishing after a signal shut the context down
            if rclpy.ok(context=self.node.context):
                raise
            self.stats.interrupted = True
        self.stats.wall_seconds = time.monotonic() - t_begin
        return self.stats

    def wait_for_delivery(self, timeout: float = 3.0) -> bool:
        """Wait until reliable subscribers acknowledged everything (before the process exits)."""
        ok = True
        for p in list(self.publishers.values()) + ([self.clock_pub] if self.clock_pub else []):
            try:
                ok = p.wait_for_all_acked(Duration(seconds=timeout)) and ok
            except Exception:
                ok = False
        return ok

    def close(self) -> None:
        self.reader.close()


class _Stopped(Exception):
    pass


def run(args: argparse.Namespace, ros_args: list[str] | None = None) -> int:
    """The ``replay`` command: returns the exit code (0 also when parts of a damaged file were skipped)."""
    # read the file before touching ROS: a non-MCAP file fails fast with a clear message
    BagReader(args.bag).close()
    node = executor = replayer = None
    spin_thread = None
    stats = None
    with ros_process(ros_args) as stop:
        try:
            node = rclpy.create_node(args.node_name, namespace=args.namespace or None)
            replayer = Replayer(node, args.bag, rate=args.rate, loop=args.loop, topics=args.topics or None,
                                exclude=args.exclude or (), start_offset=args.start_offset, clock=not args.no_clock,
                                clock_rate=args.clock_rate)
            executor = SingleThreadedExecutor()
            executor.add_node(node)

            def spin():
                try:
                    while not stop.is_set() and rclpy.ok():
                        executor.spin_once(timeout_sec=SLICE)
                except Exception:       # the context was shut down: the replay ends either way
                    pass
                stop.set()

            spin_thread = threading.Thread(target=spin, daemon=True)
            spin_thread.start()
            if args.wait_for_subscribers > 0 and not replayer.wait_for_subscribers(args.wait_for_subscribers, stop):
                node.get_logger().warning("not every topic has a subscriber; starting anyway")
            if args.delay > 0:
                stop.wait(args.delay)
            stats = replayer.run(stop)
            if not stats.interrupted:
                replayer.wait_for_delivery()
        except KeyboardInterrupt:
            pass
        finally:
            stop.set()
            if spin_thread is not None:
                spin_thread.join(timeout=5.0)
            if replayer is not None:
                replayer.close()
            release(executor, node)
    if stats is not None:
        print(stats.format(), flush=True)
    return 0
