"""sim_node as a managed device (``-p lifecycle:=true``), driven through the real lifecycle services of another
process: configure reads and validates the scene and builds the simulation, activate starts stepping and
publishing, deactivate holds, cleanup closes the recording, a configure refused on a bad scene leaves the node
unconfigured; and the plain node is unchanged (no lifecycle services, active at once)."""
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rosbags.highlevel import AnyReader

from ros_helpers import DISCOVERY_TIMEOUT, Listener, NodeProcess, call, set_params, spin_until, t_of, wall_ns

from flagbot_sim.ros.params import lifecycle_requested

SIM = "flagbot_sim.ros.sim_node"


def spin_for(ros, seconds: float) -> None:
    """Receive whatever arrives for ``seconds`` of wall time."""
    import time
    end = time.monotonic() + seconds
    spin_until(ros, lambda: time.monotonic() >= end, seconds + 10)


def test_the_lifecycle_switch_is_read_from_the_ros_arguments_only():
    assert lifecycle_requested(["sim_node", "--ros-args", "-p", "lifecycle:=true"])
    assert lifecycle_requested(["x", "--ros-args", "--param", "sim_node:lifecycle:=True", "--"])
    assert not lifecycle_requested(["x", "--ros-args", "-p", "lifecycle:=true", "-p", "lifecycle:=false"])
    assert not lifecycle_requested(["x", "-p", "lifecycle:=true"])             # not a ROS argument
    assert not lifecycle_requested(["x", "--ros-args", "-p", "other:lifecycle:=true"])     # another node's
    assert not lifecycle_requested(["x", "--ros-args", "-r", "lifecycle:=true"])           # a remapping


class Managed:
    """Clients of /sim_node/change_state and get_state on the test's probe node."""

    def __init__(self, ros):
        self.ros = ros
        self.change = ros.create_client(ChangeState, "/sim_node/change_state")
        self.get = ros.create_client(GetState, "/sim_node/get_state")

    def state(self) -> str:
        return call(self.ros, self.get, GetState.Request()).current_state.label

    def transition(self, tid: int) -> bool:
        req = ChangeState.Request()
        req.transition.id = tid
        return call(self.ros, self.change, req).success

    def close(self):
        self.ros.destroy_client(self.change)
        self.ros.destroy_client(self.get)


def test_configure_activate_deactivate_cleanup_through_the_real_services(ros, tmp_path):
    rec = tmp_path / "managed.mcap"
    node = NodeProcess(SIM, "--ros-args", "-p", "lifecycle:=true", "-p", "scene:=/no/such/scene.toml",
                       "-p", "real_time_factor:=4.0", "-p", "initial_omega:=5.0")
    lis, m = Listener(ros), Managed(ros)
    try:
        spin_until(ros, m.get.service_is_ready, DISCOVERY_TIMEOUT, "the lifecycle services")
        assert m.state() == "unconfigured"
        # nothing is simulated or published before configure
        assert ros.count_publishers("/clock") == 0 and lis.msgs["clock"] == []
        # a bad scene: the configure is refused, the node stays unconfigured and says why
        assert not m.transition(Transition.TRANSITION_CONFIGURE)
        assert m.state() == "unconfigured"
        assert node.alive()
        # a good scene, and a recording: configured (inactive) builds everything but does not step
        (res,) = set_params(ros, "sim_node", scene="design2")
        assert res.successful, res.reason
        (res,) = set_params(ros, "sim_node", record=str(rec))
        assert res.successful, res.reason
        assert m.transition(Transition.TRANSITION_CONFIGURE)
        assert m.state() == "inactive"
        spin_until(ros, lambda: ros.count_publishers("/clock") == 1, DISCOVERY_TIMEOUT, "sim_node's /clock")
        spin_for(ros, 1.0)                                  # inactive holds: no clock, no state
        assert lis.msgs["clock"] == [] and lis.msgs["joints"] == []
        # active: it steps and publishes
        assert m.transition(Transition.TRANSITION_ACTIVATE)
        assert m.state() == "active"
        lis.run_until(1.0)
        # deactivate holds the simulation where it is: the clock stops. Told apart by the source timestamps: what
        # was published before the answer (some can still be queued here when it comes) is the run up to the hold
        assert m.transition(Transition.TRANSITION_DEACTIVATE)
        t_deactivated = wall_ns()
        assert m.state() == "inactive"
        spin_for(ros, 1.5)
        t_held = max(t_of(m.clock) for m, s in zip(lis.msgs["clock"], lis.sent["clock"]) if s < t_deactivated)
        later = [t_of(m.clock) for m in lis.after("clock", t_deactivated)]
        assert len(later) <= 1 and all(t <= t_held + 0.1 for t in later), later    # (one tick may be in flight)
        # active again: simulated time carries on from where it was held
        assert m.transition(Transition.TRANSITION_ACTIVATE)
        lis.run_until(t_held + 0.5)
        # cleanup closes the recording (a valid, complete file) and leaves the node unconfigured
        assert m.transition(Transition.TRANSITION_DEACTIVATE)
        assert m.transition(Transition.TRANSITION_CLEANUP)
        assert m.state() == "unconfigured"
        spin_until(ros, lambda: ros.count_publishers("/clock") == 0, DISCOVERY_TIMEOUT, "/clock gone")
        with AnyReader([rec]) as r:
            topics = {c.topic for c in r.connections}
            clocks = [r.deserialize(raw, c.msgtype).clock for c, _, raw in r.messages()
                      if c.topic == "/clock"]
        assert {"/clock", "/joint_states", "/head_pose", "/cmd_omega"} <= topics
        last = clocks[-1].sec + 1e-9 * clocks[-1].nanosec
        assert last >= t_held + 0.5 - 0.05
        # shutdown from unconfigured ends the node's life cycle; the process exits cleanly on SIGINT
        assert m.transition(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
        assert m.state() == "finalized"
    finally:
        m.close()
        lis.close()
        code, out = node.stop()
    assert "Traceback" not in out, out
    assert code == 0, out
    assert "configure refused" in out and "/no/such/scene.toml" in out, out
    assert "recording closed" in out, out
    assert not lis.non_finite


def test_the_plain_node_has_no_lifecycle_and_runs_at_once(ros):
    node = NodeProcess(SIM, "--ros-args", "-p", "real_time_factor:=4.0")
    lis = Listener(ros)
    try:
        lis.run_until(0.2)
        services = {name for name, _ in ros.get_service_names_and_types()}
        assert "/sim_node/pause" in services and "/sim_node/change_state" not in services
    finally:
        lis.close()
        code, out = node.stop()
    assert code == 0 and "Traceback" not in out, out
