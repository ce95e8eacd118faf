"""beam_node publishes the beam library's prediction for the commanded omega_T (real rclpy, separate process)."""
import math

import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

from flagbot_sim.beam import BeamParams, solve_balance
from flagbot_sim.scene import load_scene

from ros_helpers import DISCOVERY_TIMEOUT, EVENT_TIMEOUT, NodeProcess, set_params, spin_until

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture
def beam_node(ros):
    proc = NodeProcess("flagbot_sim.ros.beam_node", "--ros-args", "-p", "scene:=design2", "-p", "n_flagella:=3",
                       "-p", "regime:=nlb")
    yield proc
    code, out = proc.stop()
    assert code == 0 and "Traceback" not in out, out


def listen(ros):
    got = {"speed": [], "omega_h": [], "omega_t": []}
    for key in got:
        ros.create_subscription(Float64, f"beam/{key}", lambda m, k=key: got[k].append(m.data), LATCHED)
    return got


def test_prediction_equals_the_beam_library(ros, beam_node):
    cmd = ros.create_publisher(Float64, "cmd_omega", 10)
    spin_until(ros, lambda: cmd.get_subscription_count() >= 1, DISCOVERY_TIMEOUT, "beam_node")
    got = listen(ros)
    expected = solve_balance(BeamParams.from_scene(load_scene("design2", ["robot.n_flagella=3"])), 12.0,
                             regime="nlb")
    cmd.publish(Float64(data=12.0))

    def matches():
        return all(got[k] and got[k][-1] == pytest.approx(v, rel=1e-12)
                   for k, v in (("speed", expected.v_h), ("omega_h", expected.omega_h), ("omega_t", expected.omega_t)))
    spin_until(ros, matches, EVENT_TIMEOUT, "the beam prediction for 12 rad/s")
    # the split adds up and the robot moves head first
    assert got["omega_h"][-1] + got["omega_t"][-1] == pytest.approx(12.0, rel=1e-9) and got["speed"][-1] > 0


def test_late_subscribers_get_the_current_prediction_and_bad_commands_change_nothing(ros, beam_node):
    cmd = ros.create_publisher(Float64, "cmd_omega", 10)
    spin_until(ros, lambda: cmd.get_subscription_count() >= 1, DISCOVERY_TIMEOUT, "beam_node")
    cmd.publish(Float64(data=6.0))
    first = listen(ros)
    spin_until(ros, lambda: first["omega_h"] and first["omega_t"]
               and first["omega_h"][-1] + first["omega_t"][-1] == pytest.approx(6.0), EVENT_TIMEOUT,
               "prediction for 6 rad/s")
    for bad in (math.nan, math.inf, 1e9):
        cmd.publish(Float64(data=bad))
    late = listen(ros)              # a new subscription: the latched value arrives without a new command
    # the three topics are separate channels: wait for each, in whatever order they arrive
    spin_until(ros, lambda: all(late[k] for k in ("speed", "omega_h", "omega_t")), EVENT_TIMEOUT,
               "latched prediction")
    assert late["omega_h"][-1] + late["omega_t"][-1] == pytest.approx(6.0)
    assert all(math.isfinite(x) for k in late for x in late[k])
    assert beam_node.alive()


def test_regime_parameter_is_validated(ros, beam_node):
    (res,) = set_params(ros, "beam_node", regime="quadratic")
    assert not res.successful and "nlb" in res.reason
    (res,) = set_params(ros, "beam_node", scene_overrides=["head.C1=-2"])
    assert not res.successful and "head.C1" in res.reason
    (res,) = set_params(ros, "beam_node", regime="lb")
    assert res.successful
