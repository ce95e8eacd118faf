"""Recorder: raw (serialized) subscriptions written to MCAP in rosbag2's layout (:mod:`flagbot_sim.bag`).

Two ways to use it:

- standalone, the ``record`` console script / ``python -m flagbot_sim record``: one node that records until
  SIGINT/SIGTERM (then the file is closed with its summary and index) or ``--duration``;
- inside an existing node (the sim_node's ``record`` parameter): ``Recorder(node, path, topics, metadata)``, then
  ``close()`` when done. It creates its subscriptions and one timer on that node and runs a small flush thread.
  The constructor opens the file and writes (and flushes) its header and metadata first: a path that cannot be
  created or written raises :class:`flagbot_sim.bag.BagWriteError` (an OSError and a BagError) before any ROS
  entity exists, and leaves no file. Later write failures (disk full, file size limit) set :attr:`Recorder.error`
  once and stop the recording; ``close()`` returns a summary whose ``error`` repeats it.

Topics: the default list :data:`flagbot_sim.topics.DEFAULT_RECORD_TOPICS` (relative names resolved in the
node's namespace), an explicit list, or :data:`ALL` (every topic visible in the graph). A topic is subscribed once
it has a publisher, so its type comes from the graph and the subscription QoS can match the publishers': RELIABLE
only if every publisher is reliable (a reliable reader does not match a best-effort writer), TRANSIENT_LOCAL if
every publisher is (so latched messages are recorded too), else VOLATILE. Topics that appear later are picked up by
a graph poll every ``poll_period`` seconds. Where tf2_msgs is not installed, /tf and /tf_static (when selected)
are derived from the recorded odom, joint_states and robot_description instead (:mod:`.tf_derive`).

Timing: log time = the middleware's receive timestamp (system clock, like rosbag2), publish time = the header stamp
of stamped types. Crash safety: the flush thread closes the chunk being filled and flushes the file when
``flush_interval`` (0.1 s) has passed since the last flush, waking exactly then and independently of the executor
(a long simulation step does not delay it), so a SIGKILL loses at most that interval plus what was still queued
in the middleware (see docs/recording.md for the measured figures).

Lost messages: a message that never reached the recorder (a KEEP_LAST queue overflowed) shows as a gap in its
publisher's sequence numbers; :attr:`Recorder.lost` counts them per topic (:mod:`flagbot_sim.bag.lost`), the
first loss on a topic is logged, and ``close()`` stores the counts in the ``flagbot_sim.lost_messages`` metadata
record and in its summary (printed by the standalone recorder, shown by ``flagbot bag-summary``).
"""
from __future__ import annotations

import argparse
import importlib
import math
import re
import sys
import threading
import time
from pathlib import Path
from typing import Iterable, Sequence

import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..bag import (DEFAULT_CHUNK_SIZE, DEFAULT_FLUSH_INTERVAL, BagError, BagWriter, QosInfo, RunMetadata,
                   WriteSummary, normalize_type, qos_to_yaml)
from ..bag.lost import LOST_METADATA_NAME, LostCounter
from ..topics import DEFAULT_RECORD_TOPICS
from .bag_args import add_record_arguments, console_main
from .runtime import SLICE, release, ros_process
from .tf_derive import recorder_deriver

#: pass as ``topics`` to record every topic visible in the graph
ALL = "all"


def message_class(type_name: str) -> type:
    """The rclpy message class of ``pkg/msg/Type``."""
    pkg, ns, name = normalize_type(type_name).split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.{ns}"), name)
    except (ImportError, AttributeError) as exc:
        raise BagError(f"message type {type_name} is not installed ({exc})") from None


def _ns(d) -> int:
    return int(getattr(d, "nanoseconds", 0))


def qos_info(profile: QoSProfile) -> QosInfo:
    """rclpy QoS profile (e.g. a publisher's, from the graph) -> the bag's QosInfo."""
    return QosInfo(history=profile.history.short_key, depth=int(profile.depth),
                   reliability=profile.reliability.short_key, durability=profile.durability.short_key,
                   liveliness=profile.liveliness.short_key,
                   deadline_ns=_ns(profile.deadline), lifespan_ns=_ns(profile.lifespan),
                   liveliness_lease_ns=_ns(profile.liveliness_lease_duration))


def adapted_qos(publishers: Sequence[QosInfo], depth: int = 1000) -> QoSProfile:
    """A subscription QoS that matches every publisher (rosbag2's adaptation rule)."""
    reliable = bool(publishers) and all(q.reliability == "reliable" for q in publishers)
    latched = bool(publishers) and all(q.durability == "transient_local" for q in publishers)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def _hidden(topic: str) -> bool:
    return any(part.startswith("_") for part in topic.split("/"))


class Recorder:
    """Record topics seen by ``node`` into an MCAP file.

    :param topics: None (the flagbot default list), a list of names (relative ones resolved in the node's
        namespace) or :data:`ALL`.
    :param metadata: :class:`flagbot_sim.bag.RunMetadata` (scene, parameters, version) written at the start.
    :param exclude: regular expressions; matching topics are not recorded (useful with ALL).
    """

    def __init__(self, node: Node, path: str | Path, topics: Iterable[str] | str | None = None,
                 metadata: RunMetadata | None = None, *, exclude: Iterable[str] = (), include_hidden: bool = False,
                 poll_period: float = 0.5, flush_interval: float = DEFAULT_FLUSH_INTERVAL,
                 chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = "zstd", overwrite: bool = False,
                 depth: int = 1000, callback_group=None):
        self.node = node
        self.all_topics = topics == ALL
        names = DEFAULT_RECORD_TOPICS if topics is None else ([] if self.all_topics else list(topics))
        self.wanted = [node.resolve_topic_name(t) for t in names]
        self.exclude = [re.compile(x) for x in exclude]
        self.include_hidden = include_hidden
        self.depth = depth
        self.writer = BagWriter(path, metadata=metadata if metadata is not None else RunMetadata(),
                                chunk_size=chunk_size, compression=compression, flush_interval=flush_interval,
                                overwrite=overwrite)
        self.path = self.writer.path
        self.lost = LostCounter()       # messages that never reached us, from the publishers' sequence numbers
        self._subs: dict[str, object] = {}
        # /tf and /tf_static derived from the recorded robot topics where tf2_msgs is missing (tf_derive.py)
        self._tf = recorder_deriver(node, self._selected)
        for t in self._tf.topics if self._tf is not None else ():
            self._subs[t] = None       # written by the deriver, never subscribed
        self._mismatch_warned: set[str] = set()
        self._error_reported = False
        self._report_lock = threading.Lock()
        self._closed = False
        self._group = callback_group or MutuallyExclusiveCallbackGroup()
        # the poll follows wall time even when the node uses sim time (a paused /clock must not stop it)
        self._poll_timer = node.create_timer(poll_period, self._poll, callback_group=self._group,
                                             clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="bag-flush", daemon=True)
        self._flusher.start()
        self._poll()

    # -- graph
    def _selected(self, topic: str) -> bool:
        if any(x.search(topic) for x in self.exclude):
            return False
        if self.all_topics:
            return self.include_hidden or not _hidden(topic)
        return topic in self.wanted

    def _poll(self) -> None:
        if self._closed or self.error:
            return
        try:
            graph = self.node.get_topic_names_and_types()
        except Exception:  # context shutting down
            return
        for topic, types in graph:
            if topic in self._subs or not self._selected(topic):
                continue
            if len(types) != 1:
                if topic not in self._mismatch_warned:
                    self._mismatch_warned.add(topic)
                    self.node.get_logger().warning(f"not recording {topic}: several types {types}")
                continue
            pubs = self.node.get_publishers_info_by_topic(topic)
            if not pubs:  # type and QoS come from publishers; a subscriber-only topic waits for one
                continue
            self._subscribe(topic, types[0], pubs)

    def _subscribe(self, topic: str, type_name: str, pubs) -> None:
        try:
            cls = message_class(type_name)
            offered = [qos_info(p.qos_profile) for p in pubs]
            type_hash = str(pubs[0].topic_type_hash) if pubs and getattr(pubs[0], "topic_type_hash", None) else ""
            self.writer.add_topic(topic, type_name, offered_qos_profiles=qos_to_yaml(offered), type_hash=type_hash)
        except BagError as exc:
            self._subs[topic] = None  # do not retry every poll
            self.node.get_logger().error(f"not recording {topic}: {exc}")
            return

        def on_message(data, info, topic=topic):
            self._on_message(topic, data, info)

        self._subs[topic] = self.node.create_subscription(cls, topic, on_message, adapted_qos(offered, self.depth),
                                                          callback_group=self._group, raw=True)
        self.node.get_logger().info(f"recording {topic} [{normalize_type(type_name)}]")

    def _on_message(self, topic: str, data: bytes, info) -> None:
        info = info if isinstance(info, dict) else {}
        if self.lost.first_loss(topic, info.get("publication_sequence_number")):
            self.node.get_logger().warning(f"messages lost on {topic} before they reached the recorder (the "
                                           "publisher's or this subscription's queue overflowed); counted at close")
        t = info.get("received_timestamp", 0) or time.time_ns()
        if not self.writer.write(topic, data, t) and self.writer.error:
            self._report_error()
        elif self._tf is not None:
            self._tf.record(self.writer, topic, data, t)

    def _report_error(self) -> None:
        """Log the first write failure, once (not once per message or topic)."""
        with self._report_lock:
            if self._error_reported or self._closed:
                return
            self._error_reported = True
        self.node.get_logger().error(f"recording stopped: {self.writer.error}; the file is readable up to the "
                                     f"last flush: flagbot bag-recover {self.path}")

    def _flush_loop(self) -> None:
        # wake when the next flush is due, not on a fixed tick: the bound on crash loss is the flush interval
        while not self._stop.wait(self.writer.seconds_to_flush()):
            self.writer.maybe_flush()
            if self.writer.error:
                self._report_error()
                return

    # -- API
    @property
    def error(self) -> str:
        """'' while every write succeeded; else the first write failure (set once, stays until closed)."""
        return self.writer.error

    @property
    def recorded_topics(self) -> dict[str, str]:
        """topic -> type of every topic subscribed so far."""
        return self.writer.topics

    def _drain(self, settle: float = 0.05) -> None:
        """Write what the middleware still holds for our subscriptions (the node's last ticks before a stop, which
        the executor no longer takes), waiting ``settle`` s once for messages still in flight."""
        for attempt in range(2):
            for topic, sub in self._subs.items():
                if sub is None:
                    continue
                try:
                    while True:
                        with sub.handle:
                            taken = sub.handle.take_message(sub.msg_type, sub.raw)
                        if taken is None:
                            break
                        self._on_message(topic, taken[0], taken[1])
                except Exception:           # rclpy already shut down, or the subscription destroyed: nothing held
                    continue
            if attempt == 0:
                time.sleep(settle)

    def close(self) -> WriteSummary:
        """Stop recording and close the file with its summary and index. Safe after rclpy shut down."""
        if not self._closed:
            self._closed = True
            self._stop.set()
            self._flusher.join(timeout=2.0)
            self._drain()
            for sub in self._subs.values():
                if sub is not None:
                    try:
                        self.node.destroy_subscription(sub)
                    except Exception:
                        pass
            try:
                self.node.destroy_timer(self._poll_timer)
            except Exception:
                pass
            if not self.writer.closed:
                self.writer.add_metadata(LOST_METADATA_NAME, self.lost.to_record())
        summary = self.writer.close()
        summary.lost = self.lost.counts()
        return summary


# ----------------------------------------------------------------------------------------------------------------
# standalone node


def scene_text(name_or_path: str) -> str:
    """A scene file's text as the CLI and the nodes read it (scene_files.py's one reader: BOM dropped, no blocking)."""
    from ..scene_files import read_scene_text, resolve_scene_path
    return read_scene_text(resolve_scene_path(name_or_path))


def fetch_parameters(node: Node, executor, target: str, timeout: float = 10.0) -> dict:
    """All parameters of node ``target`` through its parameter services."""
    from rclpy.parameter import parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient
    client = AsyncParameterClient(node, target)
    if not client.wait_for_services(timeout_sec=timeout):
        raise BagError(f"node {target} offers no parameter services within {timeout:.0f} s")
    fut = client.list_parameters()
    executor.spin_until_future_complete(fut, timeout_sec=timeout)
    if not fut.done():
        raise BagError(f"listing the parameters of {target} timed out")
    names = list(fut.result().result.names)
    fut = client.get_parameters(names)
    executor.spin_until_future_complete(fut, timeout_sec=timeout)
    if not fut.done():
        raise BagError(f"reading the parameters of {target} timed out")
    return {n: parameter_value_to_python(v) for n, v in zip(names, fut.result().values)}


def default_output() -> str:
    return time.strftime("flagbot_%Y%m%d_%H%M%S.mcap")


def run(args: argparse.Namespace, ros_args: list[str] | None = None) -> int:
    """Run the recorder node until SIGINT/SIGTERM or ``--duration``. Returns the exit code."""
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        # (0 or a negative or NaN duration used to record nothing, or forever, into a file it still wrote)
        raise BagError(f"--duration must be a positive number of seconds, got {args.duration!r}")
    extra = {}
    for kv in args.metadata or []:
        k, sep, v = kv.partition("=")
        if not sep:
            raise BagError(f"--metadata takes KEY=VALUE, got {kv!r}")
        extra[k] = v
    meta = RunMetadata(scene_toml=scene_text(args.scene) if args.scene else "", extra=extra)
    topics = ALL if args.all else (args.topics or None)
    node = executor = rec = None
    summary = None
    code = 0
    with ros_process(ros_args) as stop:
        try:
            node = rclpy.create_node(args.node_name, namespace=args.namespace or None)
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            if args.params_from:
                meta.parameters = fetch_parameters(node, executor, args.params_from)
                # the sim_node's `scene` parameter names a built-in scene or a file: store its text too
                # (overrides are in `scene_overrides`, among the parameters)
                if not meta.scene_toml and isinstance(meta.parameters.get("scene"), str):
                    try:
                        meta.scene_toml = scene_text(meta.parameters["scene"])
                    except Exception as exc:
                        node.get_logger().warning(f"scene {meta.parameters['scene']!r} not stored: {exc}")
            rec = Recorder(node, args.output or default_output(), topics, meta, exclude=args.exclude or (),
                           compression=args.compression, overwrite=args.overwrite)
            what = "all topics" if rec.all_topics else ", ".join(rec.wanted)
            print(f"recording {what} to {rec.path} (Ctrl-C to stop)", file=sys.stderr, flush=True)
            end = time.monotonic() + args.duration if args.duration else None
            while not stop.is_set() and rclpy.ok() and (end is None or time.monotonic() < end):
                executor.spin_once(timeout_sec=SLICE if end is None else max(0.0, min(SLICE, end - time.monotonic())))
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            if rec is not None:
                summary = rec.close()
            release(executor, node)
    if summary is not None:
        print(summary.format(), flush=True)
        code = 1 if summary.error else 0
    return code


def main(argv: list[str] | None = None) -> int:
    """``record`` console script: ``record [TOPIC ...] [-o out.mcap] [--all] ... [--ros-args ...]``."""
    return console_main("record", "Record flagbot topics to an MCAP file (rosbag2 layout).", add_record_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
