"""sim_node as a device: another process commands it over DDS and receives its outputs (real rclpy)."""
import math
import signal
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64, String
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import Marker

from flagbot_sim.bag import BagReader
from flagbot_sim.physics import Simulation
from flagbot_sim.scene import load_scene

from ros_helpers import (DISCOVERY_TIMEOUT, EVENT_TIMEOUT, Listener, NodeProcess, call, get_params, set_params,
                         spin_until, t_of, wall_ns)

SCENE = ["design2", ["flagellum.length=0.05"]]     # short flagella: steady within a couple of seconds
OMEGA = 10.0


@pytest.fixture
def sim_node(ros, request):
    # the motor speed in force from t = 0 is set at launch: a cmd_omega sent before unpausing travels on
    # another channel than the pause service and may arrive after simulated time has started. A bounded
    # real-time factor keeps ~10 published samples per simulated second (at full speed a 50 Hz tick spans
    # more than half a simulated second)
    omega = getattr(request, "param", OMEGA)
    proc = NodeProcess("flagbot_sim.ros.sim_node", "--ros-args", "-p", f"scene:={SCENE[0]}",
                       "-p", f"scene_overrides:={SCENE[1]!r}".replace("'", '"'), "-p", "real_time_factor:=5.0",
                       "-p", "start_paused:=true", "-p", "publish_rate:=50.0", "-p", f"initial_omega:={omega}")
    lis = Listener(ros)
    yield proc, lis
    lis.close()
    code, out = proc.stop()
    assert code == 0 and "Traceback" not in out, out


def start(ros, lis):
    spin_until(ros, lambda: lis.msgs["clock"], DISCOVERY_TIMEOUT, "/clock")
    spin_until(ros, lambda: lis.cmd.get_subscription_count() >= 1, DISCOVERY_TIMEOUT, "sim_node's cmd_omega")
    call(ros, lis.pause, SetBool.Request(data=False))


def window_mean(stamped, t0, t1):
    xs = [v for t, v in stamped if t0 <= t <= t1]
    assert xs, f"no samples in [{t0}, {t1}]"
    return float(np.mean(xs))


def test_commanded_robot_publishes_everything_and_matches_the_library(ros, sim_node):
    proc, lis = sim_node
    start(ros, lis)
    lis.run_until(3.0)
    # diagnostics come once per wall second and 3 simulated seconds take 0.6 s of wall time at this
    # real-time factor: wait for the next one rather than assume one fell inside the run
    spin_until(ros, lambda: lis.msgs["diag"], EVENT_TIMEOUT, "/diagnostics")
    for key in ("clock", "pose", "odom", "joints", "omega_h", "omega_t", "speed", "markers", "diag"):
        assert lis.msgs[key], f"nothing received on {key}"
    assert not lis.non_finite
    js = [(t_of(m.header.stamp), m.velocity) for m in lis.msgs["joints"]]
    assert all(len(m.position) == len(m.velocity) == len(m.effort) == 3 for m in lis.msgs["joints"])
    assert lis.msgs["joints"][-1].name == ["head_spin", "flagella_spin", "motor"]
    assert lis.msgs["joints"][-1].velocity[2] == OMEGA        # the command in force
    w_h = window_mean([(t, v[0]) for t, v in js], 2.0, 3.0)
    w_t = window_mean([(t, v[1]) for t, v in js], 2.0, 3.0)
    assert w_h + w_t == pytest.approx(OMEGA, rel=0.01) and w_h > 0 and w_t > 0
    v = window_mean([(t_of(m.header.stamp), m.twist.twist.linear.x) for m in lis.msgs["odom"]], 2.0, 3.0)
    # the library, same scene, same command from t = 0 (the node was paused until the command arrived)
    sim = Simulation(load_scene(SCENE[0], SCENE[1]))
    sim.set_omega(OMEGA)
    speeds, rates_h = [], []
    while sim.time < 3.0 - 1e-9:
        sim.step()
        if sim.time >= 2.0 - 1e-9:
            speeds.append(sim.observer.speed)
            rates_h.append(sim.observer.rate_h)
    assert v == pytest.approx(np.mean(speeds), rel=0.01) and v > 0
    assert w_h == pytest.approx(np.mean(rates_h), rel=0.01)
    # odometry and head_pose agree, the head moves forward (+x) from the origin
    last = lis.msgs["pose"][-1].pose.position
    assert last.x > 0 and abs(last.y) < 1e-6 and abs(last.z) < 1e-6
    # markers: one line strip per flagellum, the head, the plate
    ma = lis.msgs["markers"][-1]
    assert sorted(m.ns for m in ma.markers) == ["flagella", "flagella", "head", "plate"]
    assert all(len(m.points) == 13 for m in ma.markers if m.ns == "flagella")   # 12 edges of 4.17 mm
    # diagnostics come at 1 Hz of wall time: wait for one issued after the command took effect
    spin_until(ros, lambda: lis.msgs["diag"] and float(lis.diag_values()["omega_T_rad_s"]) == OMEGA, EVENT_TIMEOUT,
               "diagnostics reporting the command")
    assert lis.diag_values()["_level"] == DiagnosticStatus.OK


@pytest.mark.parametrize("sim_node", [4.0], indirect=True)
def test_bad_commands_are_rejected_and_the_next_good_one_is_obeyed(ros, sim_node):
    proc, lis = sim_node
    start(ros, lis)
    lis.run_until(0.5)
    for bad in (math.nan, math.inf, -math.inf, 1e9, -60.0):
        lis.cmd.publish(Float64(data=bad))
    t_bad = lis.clock
    lis.run_until(t_bad + 1.0)
    assert proc.alive()
    spin_until(ros, lambda: lis.msgs["diag"] and int(lis.diag_values()["rejected_commands"]) >= 5, EVENT_TIMEOUT,
               "rejections in diagnostics")
    assert float(lis.diag_values()["omega_T_rad_s"]) == pytest.approx(4.0)     # the last good command stayed
    lis.cmd.publish(Float64(data=7.0))
    t_good = lis.clock
    # the motor joint reports the command in force; once it is 7, head and flagella settle to share it
    # (how much simulated time that takes depends on the machine's load: not asserted)
    spin_until(ros, lambda: lis.msgs["joints"][-1].velocity[2] == 7.0, EVENT_TIMEOUT, "the new command in force")
    motor = [(t_of(m.header.stamp), m.velocity[2]) for m in lis.msgs["joints"]]
    k = next(i for i, (_, w) in enumerate(motor) if w == 7.0)
    t_obeyed = motor[k][0]
    assert t_obeyed >= t_good
    # from the last good command to the new one in one step: no rejected value was ever in force
    assert {w for _, w in motor[:k]} <= {4.0} and all(w == 7.0 for _, w in motor[k:]), motor
    lis.run_until(t_obeyed + 1.5)
    js = [(t_of(m.header.stamp), m.velocity) for m in lis.msgs["joints"]]
    rate_sum = window_mean([(t, v[0] + v[1]) for t, v in js], t_obeyed + 1.0, js[-1][0])
    assert rate_sum == pytest.approx(7.0, rel=0.01)
    assert not lis.non_finite


def test_invalid_parameters_are_refused_with_a_reason(ros, sim_node):
    proc, lis = sim_node
    start(ros, lis)
    cases = {
        "n_flagella": (99, "n_flagella"),
        "scene": ("design9", "unknown scene"),
        "scene_overrides": (["flagellum.length=-1"], "flagellum.length"),
        "publish_rate": (0.0, "publish_rate"),
        "real_time_factor": (-1.0, "real_time_factor"),
        "frame_id": ("", "frame_id"),
    }
    for name, (value, word) in cases.items():
        (res,) = set_params(ros, "sim_node", **{name: value})
        assert not res.successful and word in res.reason, (name, res.reason)
    assert get_params(ros, "sim_node", ["n_flagella", "scene"]) == {"n_flagella": 0, "scene": "design2"}
    # a valid change is applied: three flagella now
    (res,) = set_params(ros, "sim_node", n_flagella=3)
    assert res.successful
    # the markers published after the answer (ones published before it can still be queued here)
    t_rebuilt = wall_ns()
    spin_until(ros, lambda: len(lis.after("markers", t_rebuilt)) > 2, EVENT_TIMEOUT, "markers after the rebuild")
    assert [m.ns for m in lis.after("markers", t_rebuilt)[-1].markers].count("flagella") == 3


def flagella_drawn(arrays) -> set:
    """The flagellum marker ids on screen after a viewer applied ``arrays`` in order (ADD, DELETE, DELETEALL)."""
    shown = set()
    for arr in arrays:
        for m in arr.markers:
            if m.action == Marker.DELETEALL and m.ns in ("", "flagella"):
                shown.clear()
            elif m.action == Marker.DELETE and m.ns == "flagella":
                shown.discard(m.id)
            elif m.action == Marker.ADD and m.ns == "flagella":
                shown.add(m.id)
    return shown


def test_removed_flagella_are_deleted_from_the_markers(ros, sim_node):
    proc, lis = sim_node
    start(ros, lis)
    spin_until(ros, lambda: lis.msgs["markers"], DISCOVERY_TIMEOUT, "markers")
    for n, ids in ((3, {0, 1, 2}), (2, {0, 1})):
        (res,) = set_params(ros, "sim_node", n_flagella=n)
        assert res.successful, res.reason
        spin_until(ros, lambda: flagella_drawn(lis.msgs["markers"]) == ids, EVENT_TIMEOUT, f"{n} flagella on screen")
    # the shrink was announced: a DELETEALL (or a DELETE of flagellum 2) arrived after the three were drawn
    actions = [(m.action, m.ns, m.id) for arr in lis.msgs["markers"] for m in arr.markers]
    third = max(i for i, a in enumerate(actions) if a == (Marker.ADD, "flagella", 2))
    assert any(a[0] == Marker.DELETEALL or a == (Marker.DELETE, "flagella", 2) for a in actions[third:])
    # while the set stays the same, nothing is deleted (no flicker)
    n_now = len(lis.msgs["markers"])
    spin_until(ros, lambda: len(lis.msgs["markers"]) > n_now + 5, EVENT_TIMEOUT, "more markers")
    assert all(m.action == Marker.ADD for arr in lis.msgs["markers"][n_now + 1:] for m in arr.markers)


def test_robot_description_reaches_a_late_subscriber_with_the_joint_states_names(ros, sim_node):
    proc, lis = sim_node
    start(ros, lis)
    spin_until(ros, lambda: lis.msgs["joints"] and lis.msgs["odom"], DISCOVERY_TIMEOUT, "joint_states and odom")
    got = []
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    sub = ros.create_subscription(String, "robot_description", got.append, latched)   # long after it was sent
    try:
        spin_until(ros, lambda: got, DISCOVERY_TIMEOUT, "the latched robot_description")
    finally:
        ros.destroy_subscription(sub)
    root = ET.fromstring(got[-1].data)
    assert root.tag == "robot"
    # the moving joints are joint_states'; the fixed ones hold the flagellum bases (/tf_static)
    joints = {j.get("name") for j in root.iter("joint") if j.get("type") != "fixed"}
    assert joints == set(lis.msgs["joints"][-1].name)
    assert {j.get("name") for j in root.iter("joint") if j.get("type") == "fixed"} == {
        f"flagellum_{i}_base" for i in range(load_scene(SCENE[0], SCENE[1]).robot.n_flagella)}
    children = {j.find("child").get("link") for j in root.iter("joint")}
    roots = {link.get("name") for link in root.iter("link")} - children
    assert roots == {lis.msgs["odom"][-1].child_frame_id}      # the URDF hangs from odometry's child frame


def test_reset_returns_the_robot_to_the_start_and_pause_stops_time(ros, sim_node):
    proc, lis = sim_node
    start(ros, lis)
    lis.run_until(2.0)
    assert lis.msgs["pose"][-1].pose.position.x > 1e-5
    call(ros, lis.pause, SetBool.Request(data=True))
    # paused: the clock stands still while the node keeps publishing. Each check reads what was published after
    # the service's answer: what was published before it (running, or not yet reset) can still be queued here
    t_paused = wall_ns()
    spin_until(ros, lambda: len(lis.after("clock", t_paused)) > 10, EVENT_TIMEOUT, "clock ticks while paused")
    ticks = [t_of(m.clock) for m in lis.after("clock", t_paused)]
    assert max(ticks) == min(ticks) >= 2.0
    res = call(ros, lis.reset, Trigger.Request())
    assert res.success
    t_reset = wall_ns()
    spin_until(ros, lambda: len(lis.after("pose", t_reset)) > 2 and lis.after("joints", t_reset), EVENT_TIMEOUT,
               "poses and joint states after reset")
    pose = lis.after("pose", t_reset)[-1]
    p = pose.pose
    assert abs(p.position.x) < 1e-12 and abs(p.position.y) < 1e-12 and abs(p.orientation.w) > 1 - 1e-12
    j = lis.after("joints", t_reset)[-1]
    assert list(j.position) == [0.0, 0.0, 0.0]
    assert t_of(pose.header.stamp) >= max(ticks)     # the clock never runs backwards
    call(ros, lis.pause, SetBool.Request(data=False))
    lis.run_until(max(ticks) + 0.5)                                   # and runs again after resuming


def set_params_atomically(node, target: str, **values):
    """Set parameters of another node in one call (one set-parameter callback for all of them)."""
    cli = node.create_client(SetParametersAtomically, f"/{target}/set_parameters_atomically")
    req = SetParametersAtomically.Request(parameters=[Parameter(k, value=v).to_parameter_msg()
                                                      for k, v in values.items()])
    try:
        return call(node, cli, req).result
    finally:
        node.destroy_client(cli)


def test_recording_started_at_runtime_stores_the_values_being_set(ros, sim_node, tmp_path):
    proc, lis = sim_node
    start(ros, lis)
    lis.run_until(0.5)
    out = str(tmp_path / "runtime.mcap")
    # record and another parameter in one call: the set-parameter callback runs before rclpy stores either
    res = set_params_atomically(ros, "sim_node", record=out, max_omega=40.0)
    assert res.successful, res.reason
    # sim_node subscribes to its own state topics only to record them: wait for the recorder, then run on
    spin_until(ros, lambda: {"/clock", "/joint_states", "/odom"} <= {
        t for t, _ in ros.get_subscriber_names_and_types_by_node("sim_node", "/")}, DISCOVERY_TIMEOUT,
        "the recorder's subscriptions")
    lis.run_until(lis.clock + 2.0)
    (res,) = set_params(ros, "sim_node", record="")
    assert res.successful, res.reason
    assert get_params(ros, "sim_node", ["record", "max_omega"]) == {"record": "", "max_omega": 40.0}
    with BagReader(out) as r:
        assert r.report.ok, r.report.describe_loss()
        meta = r.run_metadata()
        counts = {t: info.count for t, info in r.topics.items()}
    assert meta.parameters["record"] == out
    assert meta.parameters["max_omega"] == 40.0
    assert meta.parameters["scene"] == SCENE[0] and meta.parameters["scene_overrides"] == SCENE[1]
    for topic in ("/clock", "/joint_states", "/odom", "/head_pose"):
        assert counts.get(topic, 0) > 5, (topic, counts)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_shuts_down_cleanly_on_signals(ros, sig):
    proc = NodeProcess("flagbot_sim.ros.sim_node", "--ros-args", "-p", "scene:=design2", "-p", "initial_omega:=5.0")
    lis = Listener(ros)
    try:
        spin_until(ros, lambda: len(lis.msgs["clock"]) > 3, DISCOVERY_TIMEOUT, "/clock")
    finally:
        lis.close()
    code, out = proc.stop(sig)
    assert code == 0, out
    assert "Traceback" not in out and "error" not in out.lower()


def test_fresh_recording_carries_tf_that_rosbags_decodes_and_that_matches_head_pose(ros, tmp_path):
    """A recording made with record:= holds /tf and /tf_static (tf2_msgs/msg/TFMessage), whether sim_node could
    publish them (tf2_msgs installed) or its recorder derived them. Read with rosbags' own Jazzy typestore (not
    the file's schema): world -> head equals head_pose at every stamp from the first on, the joint transforms are
    joint_states' angles, /tf_static holds the flagellum-base frames of the URDF and follows a rebuild."""
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from flagbot_sim.ros import tf_derive
    from flagbot_sim.urdf import base_link, base_position

    out = tmp_path / "tf.mcap"
    proc = NodeProcess("flagbot_sim.ros.sim_node", "--ros-args", "-p", f"scene:={SCENE[0]}",
                       "-p", f"scene_overrides:={SCENE[1]!r}".replace("'", '"'), "-p", "n_flagella:=3",
                       "-p", "real_time_factor:=5.0", "-p", "start_paused:=true", "-p", f"initial_omega:={OMEGA}",
                       "-p", f"record:={out}")
    lis = Listener(ros)
    try:
        start(ros, lis)
        # 2 s of simulated time either side of the rebuild: at 50 Hz of wall time and real-time factor 5 about 40
        # publications; with 1 s each the count was 17-27 on a loaded machine, too close to the bound below
        lis.run_until(2.0)
        (res,) = set_params(ros, "sim_node", n_flagella=4)      # a rebuild: a new URDF, new fixed frames
        assert res.successful, res.reason
        lis.run_until(lis.clock + 2.0)
    finally:
        lis.close()
        code, log = proc.stop()
    assert code == 0 and "Traceback" not in log, log

    if tf_derive.tf_message_class() is None:
        assert log.count("not publishing /tf and /tf_static") == 1, log      # said once
        assert "deriving /tf and /tf_static" in log, log

    def plain(m):
        return [(t.header.stamp.sec, t.header.stamp.nanosec, t.header.frame_id, t.child_frame_id,
                 t.transform.translation.x, t.transform.translation.y, t.transform.translation.z,
                 t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w)
                for t in m.transforms]

    jazzy = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([Path(out)]) as ar:
        conns = {c.topic: c for c in ar.connections}
        assert conns["/tf"].msgtype == conns["/tf_static"].msgtype == "tf2_msgs/msg/TFMessage"
        assert [q.durability.name for q in conns["/tf_static"].ext.offered_qos_profiles] == ["TRANSIENT_LOCAL"]
        msgs = {t: [] for t in ("/tf", "/tf_static", "/head_pose", "/joint_states")}
        for c, _, raw in ar.messages(connections=[conns[t] for t in msgs]):
            m = jazzy.deserialize_cdr(raw, c.msgtype)
            if c.topic.startswith("/tf"):        # the file's own schema reads the same message
                assert plain(ar.deserialize(raw, c.msgtype)) == plain(m)
            msgs[c.topic].append(m)

    def ns(stamp):
        return stamp.sec * 10 ** 9 + stamp.nanosec

    def vec(v, *names):
        return tuple(getattr(v, n) for n in names)

    head, joints = {}, {}
    for m in msgs["/tf"]:
        for t in m.transforms:
            key = (t.header.frame_id, t.child_frame_id)
            tr = vec(t.transform.translation, "x", "y", "z") + vec(t.transform.rotation, "x", "y", "z", "w")
            (head if key == ("world", "head") else joints.setdefault(key, {}))[ns(t.header.stamp)] = tr
    poses = {ns(m.header.stamp): vec(m.pose.position, "x", "y", "z") + vec(m.pose.orientation, "x", "y", "z", "w")
             for m in msgs["/head_pose"]}
    assert len(head) > 20
    first = min(head)
    assert head == {t: p for t, p in poses.items() if t >= first}      # every pose from the first on, exactly
    assert set(joints) == {("head", "head_axis"), ("head_axis", "flagella"), ("head", "plate")}
    motor = {ns(m.header.stamp): m.position[list(m.name).index("motor")] for m in msgs["/joint_states"]}
    plate = joints[("head", "plate")]
    assert len(plate) > 20 and max(motor.values()) > 1.0
    for t, tr in plate.items():     # a turn by the motor angle about -x
        q = motor[t]
        assert tr == pytest.approx((0, 0, 0, -math.sin(q / 2), 0, 0, math.cos(q / 2)), abs=1e-12)
    # /tf_static: the fixed frames of the URDF in force, again after the rebuild
    statics = [{t.child_frame_id: (t.header.frame_id, vec(t.transform.translation, "x", "y", "z"))
                for t in m.transforms} for m in msgs["/tf_static"]]
    assert len(statics) == 2
    for n, frames in zip((3, 4), statics):
        sc = load_scene(SCENE[0], [*SCENE[1], f"robot.n_flagella={n}"])
        assert set(frames) == {base_link(i) for i in range(n)}
        for i in range(n):
            assert frames[base_link(i)][0] == "plate"
            assert frames[base_link(i)][1] == pytest.approx(base_position(sc, i), abs=1e-9)
