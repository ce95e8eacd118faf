"""Helpers for the recording tests (tests/test_bag_*.py).

Run as a script it is a small ROS node for the tests' other processes:

    python tests/bag_testlib.py publish --ns /t --rounds 20 --rate 20 --log out.jsonl
        one message of each flagbot message type per round on the default flagbot topics in namespace --ns,
        after every publisher has a subscriber (the recorder); each publish is logged (topic, round, wall time just
        before and just after the publish call)
    python tests/bag_testlib.py stream --topic /t/omega_h --rate 100 --log out.jsonl
        Float64 k on --topic at --rate Hz until SIGINT/SIGTERM, each publish logged with its wall time
    python tests/bag_testlib.py latched --topic /t/latched
        one TRANSIENT_LOCAL message, published before anyone listens, plus a BEST_EFFORT stream on --topic2
    python tests/bag_testlib.py clockwatch --topic /t/speed --count 20 --out out.json
        a use_sim_time node: {"messages": for each Float64 received [data, node clock (sim time) ns, wall time ns,
        receive timestamp ns], "clocks": for each /clock received [clock ns, receive timestamp ns]}
    python tests/bag_testlib.py selfrecord --ns /t --count 10 --out out.mcap
        a node that records its own topic with an in-process flagbot_sim.ros.recorder.Recorder
    python tests/bag_testlib.py clocklog --topic /clock --log out.txt
        subscribes to rosgraph_msgs/Clock on --topic until SIGINT/SIGTERM; logs "sim_ns wall_ns" per message
    python tests/bag_testlib.py openfail --out PATH [--out PATH ...]
        tries Recorder(node, PATH, None, RunMetadata(...)) for each PATH; prints one JSON line per PATH: what was
        raised, whether a file was left behind, how many subscriptions the node has afterwards
    python tests/bag_testlib.py fullself --ns /t --out out.mcap
        (run it under a file size limit, see `limited`) a node recording its own 1 kHz topic until the recorder
        reports a write error, then publishing on for a while; prints JSON: the error as first seen, as seen later
        and as close() reports it, and the messages written before and after

Message content is a pure function of (topic, round) — :func:`make_message` — so a test can rebuild what was
published and compare it, decoded, with what a reader decodes. Values are exactly representable in float32 and
every array is non-empty (rosbags cannot read an empty float64 array written by Fast DDS; see ROS_NOTES).
"""
from __future__ import annotations

import argparse
import array
import dataclasses
import json
import os
import time

import ros_helpers  # tests/ is on sys.path, as a script and under pytest
from ros_helpers import DISCOVERY_TIMEOUT, EVENT_TIMEOUT, ChildProcess

ROOT = ros_helpers.ROOT        # the test modules import it from here

# topic (relative to the namespace, or absolute) -> type; the default flagbot topics, one per message type
TOPIC_TYPES = {
    "omega_h": "std_msgs/msg/Float64",
    "head_pose": "geometry_msgs/msg/PoseStamped",
    "joint_states": "sensor_msgs/msg/JointState",
    "markers": "visualization_msgs/msg/MarkerArray",
    "/clock": "rosgraph_msgs/msg/Clock",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "odom": "nav_msgs/msg/Odometry",
}


def full_topic(ns: str, name: str) -> str:
    return name if name.startswith("/") else ns.rstrip("/") + "/" + name


def _stamp(msg, k: int) -> None:
    msg.header.stamp.sec = 100 + k
    msg.header.stamp.nanosec = 1000 * k + 7
    msg.header.frame_id = "world"


def make_message(name: str, k: int):
    """Message number ``k`` of topic ``name`` (a key of TOPIC_TYPES): deterministic, every field set."""
    from builtin_interfaces.msg import Duration
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import Point
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import ColorRGBA, Float64
    from visualization_msgs.msg import Marker, MarkerArray, UVCoordinate
    from geometry_msgs.msg import PoseStamped
    x = 0.25 * k
    if name == "omega_h":
        return Float64(data=1.5 + x)
    if name == "head_pose":
        m = PoseStamped()
        _stamp(m, k)
        m.pose.position.x, m.pose.position.y, m.pose.position.z = x, -x, 0.5
        m.pose.orientation.w, m.pose.orientation.x = 0.5, 0.5
        m.pose.orientation.y, m.pose.orientation.z = 0.5, 0.5
        return m
    if name == "joint_states":
        m = JointState()
        _stamp(m, k)
        m.name = ["head_spin", "flagella_spin"]
        m.position = [x, -x]
        m.velocity = [1.0 + x, -2.0]
        m.effort = [0.125, -0.125 * k]
        return m
    if name == "markers":
        arr = MarkerArray()
        for i in range(2):
            mk = Marker()
            _stamp(mk, k)
            mk.ns, mk.id, mk.type, mk.action = "flagellum", i, Marker.LINE_STRIP, Marker.ADD
            mk.pose.orientation.w = 1.0
            mk.scale.x = mk.scale.y = mk.scale.z = 0.003125
            mk.color = ColorRGBA(r=1.0, g=0.5, b=0.25, a=1.0)
            mk.lifetime = Duration(sec=1, nanosec=500)
            mk.frame_locked = bool(i)
            mk.points = [Point(x=x + j, y=float(i), z=-0.5 * j) for j in range(4)]
            mk.colors = [ColorRGBA(r=0.0, g=0.25 * j, b=1.0, a=1.0) for j in range(4)]
            mk.texture_resource = "embedded://none"
            mk.texture.format = "png"
            mk.texture.data = [1, 2, 3, k % 256]
            _stamp(mk.texture, k)
            mk.uv_coordinates = [UVCoordinate(u=0.5, v=0.25 * j) for j in range(4)]
            mk.text = f"flagellum {i}"
            mk.mesh_resource = "embedded://mesh"
            mk.mesh_file.filename = "mesh.stl"
            mk.mesh_file.data = [9, 8, k % 256]
            mk.mesh_use_embedded_materials = True
            arr.markers.append(mk)
        return arr
    if name == "/clock":
        m = Clock()
        m.clock.sec, m.clock.nanosec = 100 + k // 20, (k % 20) * 50_000_000
        return m
    if name == "/diagnostics":
        m = DiagnosticArray()
        _stamp(m, k)
        m.status = [DiagnosticStatus(level=DiagnosticStatus.OK, name="sim", message=f"step {k}",
                                     hardware_id="flagbot",
                                     values=[KeyValue(key="newton", value=str(k)), KeyValue(key="dt", value="0.01")])]
        return m
    if name == "odom":
        m = Odometry()
        _stamp(m, k)
        m.child_frame_id = "head"
        m.pose.pose.position.x = x
        m.pose.pose.orientation.w = 1.0
        m.pose.covariance = [0.5 * i for i in range(36)]
        m.twist.twist.linear.x = -x
        m.twist.twist.angular.x = 2.0 + x
        m.twist.covariance = [0.25 * i for i in range(36)]
        return m
    raise KeyError(name)


def to_plain(o):
    """Decoded message of any reader (rclpy, mcap_ros2, rosbags) -> nested dicts/lists of Python scalars."""
    if isinstance(o, (bool, int, float, str)) or o is None:
        return o
    if isinstance(o, (bytes, bytearray)):
        return o[0] if len(o) == 1 else list(o)      # rclpy 'byte' is a 1-byte bytes, others decode it as int
    if hasattr(o, "tolist"):
        return to_plain(o.tolist())
    if isinstance(o, (list, tuple, array.array)):
        return [to_plain(x) for x in o]
    if hasattr(o, "get_fields_and_field_types"):
        names = list(o.get_fields_and_field_types())
    elif dataclasses.is_dataclass(o):
        # rosbags keeps constants (ARROW, OK, ...) as fields; ROS field names are lower case
        names = [f.name for f in dataclasses.fields(o) if not f.name.startswith("__") and f.name == f.name.lower()]
    else:
        names = list(getattr(type(o), "__slots__", None) or vars(o))
    return {n: to_plain(getattr(o, n)) for n in names}


def stamp_ns(msg) -> int | None:
    h = getattr(msg, "header", None)
    return None if h is None else h.stamp.sec * 1_000_000_000 + h.stamp.nanosec


# ----------------------------------------------------------------------------------------------------------------
# processes


def record(out: str, *args: str) -> ChildProcess:
    return ChildProcess("-m", "flagbot_sim.ros.recorder", "-o", out, *args)


def start_helper(*args: str) -> ChildProcess:
    return ChildProcess(os.path.abspath(__file__), *args)


class LimitedProcess(ChildProcess):
    """``python ARGV`` in a child process that cannot write files beyond ``fsize`` bytes: a full disk as that
    process sees it (RLIMIT_FSIZE set by preexec_fn: writes past the limit fail with EFBIG, since CPython ignores
    SIGXFSZ and the ignore survives exec). Its output goes through a pipe, which the limit does not cover. (Fast
    DDS cannot create its shared-memory segments under the limit, says so, and talks over loopback UDP.)"""

    def __init__(self, fsize: int, *argv: str):
        import resource
        import subprocess
        import sys
        import threading
        env = dict(os.environ)
        from flagbot_sim.ros.dds import loopback_only
        assert loopback_only(env), "conftest.py keeps DDS on this machine"
        assert env.get("ROS_DOMAIN_ID")
        env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
        self._chunks: list[bytes] = []

        def limit():
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

        self.proc = subprocess.Popen([sys.executable, *argv], env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, cwd=ROOT, preexec_fn=limit)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for chunk in iter(lambda: self.proc.stdout.read1(65536), b""):
            self._chunks.append(chunk)

    def output(self) -> str:
        if self.proc.poll() is not None:
            self._reader.join(timeout=5.0)
        return b"".join(self._chunks).decode(errors="replace")


def limited(fsize: int, *argv: str) -> LimitedProcess:
    return LimitedProcess(fsize, *argv)


def wait_for(predicate, timeout: float, what: str, proc: ChildProcess | None = None):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = predicate()
        if v:
            return v
        if proc is not None and not proc.alive():
            raise AssertionError(f"process exited while waiting for {what}:\n{proc.output()}")
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}"
                         + (f"\n{proc.output()}" if proc is not None else ""))


def bag_messages(path: str, topics=None) -> int:
    """Messages readable so far in a file being written (0 if it does not exist yet); only those on ``topics`` if
    given (a recorder adds /tf derived from the robot's topics where tf2_msgs is missing)."""
    from flagbot_sim.bag import BagError, BagReader
    if not os.path.exists(path):
        return 0
    try:
        with BagReader(path) as r:
            if topics is None:
                return r.report.messages
            return sum(info.count for t, info in r.topics.items() if t in topics)
    except BagError:
        return 0


@dataclasses.dataclass
class RunRecord:
    """A recorded run reduced to what a command-driven re-simulation needs: the run metadata (scene, parameters,
    version) and the command stream. Times in seconds: ``t`` = log (receive) time since the first message of the
    bag, ``sim_t`` = simulation time from the recorded /clock at that moment (None without /clock)."""
    path: str
    metadata: object                                     # flagbot_sim.bag.RunMetadata or None
    start_ns: int | None
    cmd_omega: list[tuple[float, float | None, float]]  # (t, sim_t, omega_T rad/s)
    report: object                                       # flagbot_sim.bag.ScanReport

    @property
    def scene_toml(self) -> str:
        return self.metadata.scene_toml if self.metadata else ""

    @property
    def parameters(self) -> dict:
        return self.metadata.parameters if self.metadata else {}


def read_run(path, namespace: str | None = None) -> RunRecord:
    """Scene, parameters and the decoded ``cmd_omega`` stream with log and simulation times, put together from
    the bag package's parts (run metadata, topic lookup by relative name, one-pass decoding, /clock mapping)."""
    from flagbot_sim.bag import BagReader, SimTimeMap, find_topic
    from flagbot_sim.topics import CLOCK, CMD_OMEGA
    with BagReader(path) as r:
        rep = r.report
        meta = r.run_metadata()
        cmds = []
        topic = find_topic(r.topics, CMD_OMEGA, namespace)
        if topic is not None:
            rows = r.decoded_many([topic, CLOCK])
            smap = SimTimeMap.from_rows(rows[CLOCK])
            for lt, _, m in rows[topic]:
                cmds.append(((lt - rep.start_ns) * 1e-9, float(smap(lt)) if smap else None, float(m.data)))
        return RunRecord(str(r.path), meta, rep.start_ns, cmds, rep)


# ----------------------------------------------------------------------------------------------------------------
# the node side (runs in child processes)


def _node_main(fn, args):
    """Run ``fn(node, args)``; it returns the executor it spun the node with, if any, for the teardown."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from flagbot_sim.ros.runtime import release
    rclpy.init()
    node = rclpy.create_node(f"bag_test_{args.mode}", namespace=args.ns)
    executor = None
    try:
        executor = fn(node, args)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():       # publishing after SIGINT/SIGTERM shut the context down is the normal end
            raise
    finally:
        release(executor, node)
        rclpy.try_shutdown()


def _wait_subscribed(node, pubs, timeout=DISCOVERY_TIMEOUT):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if all(p.get_subscription_count() > 0 for p in pubs):
            return
        time.sleep(0.02)
    raise SystemExit(f"no subscriber after {timeout} s on " + ", ".join(p.topic_name for p in pubs
                                                                        if p.get_subscription_count() == 0))


def _publish(node, args):
    from rclpy.duration import Duration
    from rclpy.qos import QoSProfile
    pubs = {}
    for name in TOPIC_TYPES:
        cls = type(make_message(name, 0))
        pubs[name] = node.create_publisher(cls, full_topic(args.ns, name), QoSProfile(depth=100))
    _wait_subscribed(node, list(pubs.values()))
    log = open(args.log, "w")
    t0 = time.monotonic()
    for k in range(args.rounds):
        target = t0 + k / args.rate
        while time.monotonic() < target:
            time.sleep(min(0.005, target - time.monotonic()))
        for name, p in pubs.items():
            msg = make_message(name, k)
            before = time.time_ns()          # no delivery can be stamped before this, however the OS schedules
            p.publish(msg)
            log.write(json.dumps({"topic": full_topic(args.ns, name), "k": k, "before_ns": before,
                                  "wall_ns": time.time_ns()}) + "\n")
    log.close()
    for p in pubs.values():
        p.wait_for_all_acked(Duration(seconds=5.0))


def _stream(node, args):
    from std_msgs.msg import Float64
    pub = node.create_publisher(Float64, args.topic, 100)
    _wait_subscribed(node, [pub])
    log = open(args.log, "w", buffering=1)
    t0 = time.monotonic()
    k = 0
    while True:
        target = t0 + k / args.rate
        while time.monotonic() < target:
            time.sleep(min(0.002, max(0.0, target - time.monotonic())))
        pub.publish(Float64(data=float(k)))
        log.write(f"{k} {time.time_ns()}\n")
        k += 1


def _latched(node, args):
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64
    latched = node.create_publisher(Float64, args.topic,
                                    QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    latched.publish(Float64(data=42.0))
    be = node.create_publisher(Float64, args.topic2, QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    print("latched published", flush=True)
    k = 0
    while rclpy.ok():
        be.publish(Float64(data=float(k)))
        k += 1
        time.sleep(0.02)


def _clockwatch(node, args):
    import rclpy
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64
    node.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, True)])
    from rosgraph_msgs.msg import Clock
    got, clocks = [], []
    # besides the node's (sim time) clock at the callback, the middleware's receive timestamps of every /clock and
    # every message: they are taken on arrival, in arrival order, so a callback run late (this process starved)
    # does not change them
    node.create_subscription(
        Float64, args.topic, lambda m, info: got.append((m.data, node.get_clock().now().nanoseconds, time.time_ns(),
                                                         info["received_timestamp"])), 100)
    node.create_subscription(Clock, "/clock", lambda m, info: clocks.append(
        (m.clock.sec * 1_000_000_000 + m.clock.nanosec, info["received_timestamp"])), 1000)
    print("clockwatch ready", flush=True)
    end = time.monotonic() + args.timeout
    while rclpy.ok() and len(got) < args.count and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    with open(args.out, "w") as f:
        json.dump({"messages": got, "clocks": clocks}, f)


def _selfrecord(node, args):
    """The sim_node's use: a Recorder inside a node that also publishes what it records."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64

    from flagbot_sim.bag import RunMetadata
    from flagbot_sim.ros.recorder import Recorder
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    pub = node.create_publisher(Float64, "speed", 10)     # relative: resolved in the node's namespace /t
    rec = Recorder(node, args.out, ["speed"], RunMetadata(scene_toml="[robot]\n", parameters={"dt": 0.01}))
    end = time.monotonic() + DISCOVERY_TIMEOUT
    while not (rec.recorded_topics and pub.get_subscription_count() > 0):
        ex.spin_once(timeout_sec=0.05)
        if time.monotonic() > end:
            raise SystemExit("the recorder did not subscribe to its own node's topic")
    for k in range(args.count):
        pub.publish(Float64(data=float(k)))
        ex.spin_once(timeout_sec=0.01)
    end = time.monotonic() + EVENT_TIMEOUT
    while rec.writer.message_count < args.count and time.monotonic() < end and rclpy.ok():
        ex.spin_once(timeout_sec=0.05)
    print(rec.close().format(), flush=True)
    return ex


def _clocklog(node, args):
    """What a simulator published: every /clock received, with its wall receive time (line-buffered log, so a
    test can read it while this runs)."""
    import rclpy
    from rosgraph_msgs.msg import Clock
    log = open(args.log, "w", buffering=1)
    node.create_subscription(
        Clock, args.topic, lambda m: log.write(f"{m.clock.sec * 1_000_000_000 + m.clock.nanosec} {time.time_ns()}\n"),
        100)
    print("clocklog ready", flush=True)
    while rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.05)


def _openfail(node, args):
    """Recorder's promise when the target cannot be written: an OSError (and BagError) from the constructor, no
    file left behind, no ROS entity created."""
    from flagbot_sim.bag import BagError, RunMetadata
    from flagbot_sim.ros.recorder import Recorder
    for path in args.out:
        subs = len(list(node.subscriptions)) + len(list(node.timers))
        got = {"path": path}
        try:
            rec = Recorder(node, path, None, RunMetadata(scene_toml="[robot]\n" + "# padding\n" * 50))
            got["raised"] = None
            rec.close()
        except Exception as exc:         # noqa: BLE001 - the test wants to see whatever it is
            got.update(raised=type(exc).__name__, oserror=isinstance(exc, OSError), bagerror=isinstance(exc, BagError),
                       message=str(exc))
        target = path if path.endswith(".mcap") else path + ".mcap"
        got["left_behind"] = os.path.exists(target)
        got["new_entities"] = len(list(node.subscriptions)) + len(list(node.timers)) - subs
        print(json.dumps(got), flush=True)


def _fullself(node, args):
    """A node recording its own topic (the sim_node's use of Recorder) when the disk fills up."""
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64

    from flagbot_sim.bag import RunMetadata
    from flagbot_sim.ros.recorder import Recorder
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    pub = node.create_publisher(Float64, "speed", 100)
    rec = Recorder(node, args.out, ["speed"], RunMetadata(parameters={"test": "fullself"}))
    out = {"error_at_start": rec.error}
    k, end = 0, time.monotonic() + 60.0
    while not rec.error:
        if time.monotonic() > end:
            raise SystemExit("the recorder never reported a write error")
        pub.publish(Float64(data=float(k)))
        k += 1
        ex.spin_once(timeout_sec=0.001)
    out.update(first_error=rec.error, written_at_error=rec.writer.message_count, published_at_error=k)
    later = time.monotonic() + 1.0
    while time.monotonic() < later:          # the recorder keeps receiving: nothing more may be written
        pub.publish(Float64(data=float(k)))
        k += 1
        ex.spin_once(timeout_sec=0.001)
    out.update(later_error=rec.error, written_later=rec.writer.message_count, published=k)
    summary = rec.close()
    out.update(summary_error=summary.error, summary_closed=summary.closed, summary_messages=summary.messages)
    print("RESULT " + json.dumps(out), flush=True)
    return ex


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("mode", choices=["publish", "stream", "latched", "clockwatch", "selfrecord", "clocklog", "openfail",
                                    "fullself"])
    p.add_argument("--ns", default="/t")
    p.add_argument("--rounds", type=int, default=20)
    p.add_argument("--rate", type=float, default=20.0)
    p.add_argument("--log", default=os.devnull)
    p.add_argument("--topic", default="/t/omega_h")
    p.add_argument("--topic2", default="/t/best_effort")
    p.add_argument("--count", type=int, default=20)
    p.add_argument("--timeout", type=float, default=30.0)
    p.add_argument("--out", default=None, action="append")
    args = p.parse_args(argv)
    fn = {"publish": _publish, "stream": _stream, "latched": _latched, "clockwatch": _clockwatch,
          "selfrecord": _selfrecord, "clocklog": _clocklog, "openfail": _openfail, "fullself": _fullself}[args.mode]
    if args.mode != "openfail":
        args.out = args.out[-1] if args.out else os.devnull
    _node_main(fn, args)


if __name__ == "__main__":
    main()
