"""The simulated robot as a device (flagbot_sim.device), without ROS: sim_node's parameter transaction (all or
nothing), what a rebuild keeps and what starts again, the motor command's checks. sim_node adapts this class; its
live behaviour over DDS is in test_ros_sim_node.py and test_ros_sim_params.py."""
import math
import subprocess
import sys

import numpy as np
import pytest

from flagbot_sim.device import PARAMS, Device, Refused
from flagbot_sim.scene import SceneError


def start_values(**changes):
    return dict({s.name: s.default for s in PARAMS}, **changes)


@pytest.fixture
def device():
    d = Device(start_values())
    d.configure()
    return d


class FileOutput:
    """An output with an effect outside the device (as a recording's file): created at open, removed at discard."""
    keys = ("record",)

    def __init__(self):
        self.discarded = []

    def open(self, values, sim):
        if not values["record"]:
            return None
        with open(values["record"], "w") as f:
            f.write(sim.scene.to_toml())
        return values["record"]

    def discard(self, path):
        self.discarded.append(path)
        import os
        os.remove(path)


class PortOutput:
    """An output that refuses a port it cannot serve on (as the live view)."""
    keys = ("foxglove_port", "foxglove_host")

    def __init__(self, taken=()):
        self.taken = set(taken)

    def open(self, values, sim):
        if values["foxglove_port"] in self.taken:
            raise Refused(f"foxglove_port = {values['foxglove_port']} is in use")
        return values["foxglove_port"] or None

    def discard(self, port):
        pass


def state_of(d: Device):
    return dict(d.values), d.sim, d.time_offset, d.sim.omega_T, d.sim.time


def test_the_module_imports_no_rclpy():
    code = "import sys, flagbot_sim.device; print('rclpy' in sys.modules, 'rcl_interfaces' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "False"]


@pytest.mark.parametrize("bad, name, shown", [
    ({"frame_id": "my frame"}, "frame_id", "'my frame'"),
    ({"initial_omega": math.nan}, "initial_omega", "nan"),
    ({"publish_rate": 5000.0}, "publish_rate", "5000.0"),
    ({"real_time_factor": "fast"}, "real_time_factor", "'fast'"),
    ({"scene": "design1\nx"}, "scene", "'design1\\nx'"),
    ({"child_frame_id": "world"}, "frame_id", "'world'"),          # the same frame twice
])
def test_a_batch_with_one_bad_value_changes_nothing_and_names_it(device, bad, name, shown):
    before = state_of(device)
    batch = {"publish_rate": 20.0, "max_omega": 10.0, "n_flagella": 3, **bad}
    with pytest.raises(Refused) as err:
        device.prepare(batch, (FileOutput(), PortOutput()))
    reason = str(err.value)
    assert name in reason and shown in reason, reason
    assert state_of(device) == before
    assert device.sim.scene.robot.n_flagella == before[1].scene.robot.n_flagella     # the rebuild never ran


def test_a_scene_that_cannot_be_built_refuses_the_batch_naming_the_key(device):
    before = state_of(device)
    with pytest.raises(SceneError, match="flagellum.length"):
        device.prepare({"max_omega": 10.0, "scene_overrides": ["flagellum.length=-1"]})
    assert state_of(device) == before


def test_an_output_refusing_after_the_build_discards_what_was_opened_and_changes_nothing(device, tmp_path):
    before = state_of(device)
    rec, view = FileOutput(), PortOutput(taken={8765})
    path = str(tmp_path / "run.mcap")
    with pytest.raises(Refused, match="foxglove_port = 8765"):
        device.prepare({"n_flagella": 3, "record": path, "foxglove_port": 8765}, (rec, view))
    assert rec.discarded == [path] and not (tmp_path / "run.mcap").exists()      # the file it created is gone
    assert state_of(device) == before


def test_a_good_batch_is_applied_whole(device, tmp_path):
    rec, view = FileOutput(), PortOutput()
    path = str(tmp_path / "run.mcap")
    new = {"publish_rate": 20.0, "max_omega": 10.0, "frame_id": "map", "n_flagella": 3, "record": path,
           "foxglove_port": 8766}
    plan = device.prepare(new, (rec, view))
    assert device.values["publish_rate"] == 50.0 and device.sim.scene.robot.n_flagella == 2    # not yet in force
    old = device.apply(plan)
    assert old is not None and old is not device.sim
    assert {k: device.values[k] for k in new} == new
    assert device.sim.scene.robot.n_flagella == 3
    assert plan.opened == {rec: path, view: 8766}
    # the file was opened with the new simulation's scene (a recording's metadata is the scene it records)
    assert "n_flagella = 3" in (tmp_path / "run.mcap").read_text()
    # the new max_omega is in force: 20 rad/s was a good command before, now it is refused
    assert "max_omega = 10" in device.command(20.0) and device.sim.omega_T == 0.0
    assert device.command(9.0) is None and device.sim.omega_T == 9.0


def test_values_that_leave_the_scene_alone_keep_the_simulation(device):
    sim = device.sim
    device.apply(device.prepare({"real_time_factor": 3.0, "marker_rate": 0.0}))
    assert device.sim is sim and device.values["real_time_factor"] == 3.0


def test_a_rebuild_keeps_the_clock_and_the_command_and_restarts_the_robot(device):
    assert device.command(5.0) is None
    for _ in range(20):
        device.sim.step()
    t_before = device.sim_time
    old_snap = device.sim.snapshot()
    assert t_before > 0 and device.sim.motor_angle != 0.0 and old_snap.omega_h != 0.0
    device.apply(device.prepare({"n_flagella": 3}))
    sim = device.sim
    assert device.sim_time == t_before                    # the device's clock does not go back
    assert sim.time == 0.0 and sim.steps == 0
    assert sim.omega_T == 5.0                             # the operator's command carries over
    assert sim.motor_angle == 0.0                         # the robot starts from the new scene's initial state
    np.testing.assert_array_equal(sim.state.q, sim.initial.q)      # pose and shape: the initial ones, at rest
    np.testing.assert_array_equal(sim.state.v, sim.initial.v)
    assert not np.allclose(old_snap.position, device.sim.snapshot().position)   # (the old robot had moved)
    sim.step()
    assert device.sim_time == pytest.approx(t_before + sim.dt, rel=1e-12)


def test_reset_keeps_the_clock_and_the_command(device):
    device.command(-4.0)
    for _ in range(10):
        device.sim.step()
    t = device.sim_time
    device.reset()
    assert device.sim_time == t and device.sim.time == 0.0
    assert device.sim.omega_T == -4.0 and device.sim.motor_angle == 0.0


def test_a_released_device_keeps_its_clock_and_configures_again_from_its_values(device):
    for _ in range(5):
        device.sim.step()
    t = device.sim_time
    device.release()
    assert not device.configured
    # unconfigured, a set is only checked (no build), and its values are what the next configure builds
    with pytest.raises(Refused, match="initial_omega"):
        device.prepare({"initial_omega": math.inf})
    plan = device.prepare({"n_flagella": 3, "initial_omega": 2.5})
    assert plan.sim is None
    device.apply(plan)
    sim = device.configure()
    assert sim.scene.robot.n_flagella == 3 and sim.omega_T == 2.5 and device.sim_time == t


def test_a_bad_command_is_refused_and_the_last_good_one_stays(device):
    assert device.command(3.0) is None
    for w in (math.nan, math.inf, -60.0):
        assert device.command(w) is not None
        assert device.sim.omega_T == 3.0


def test_a_bad_start_value_or_an_unknown_name_is_refused():
    with pytest.raises(Refused, match="max_omega = 0.0"):
        Device(start_values(max_omega=0.0))
    with pytest.raises(Refused, match="unknown parameter 'rate'"):
        Device(start_values()).prepare({"rate": 3.0})


class WallClock:
    """A virtual wall clock: the schedule's time moves only when the test says so."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def clocked_device(**changes):
    clock = WallClock()
    d = Device(start_values(**changes), clock=clock)
    d.configure()
    return d, clock


def test_a_tick_steps_to_the_schedule_and_nothing_while_paused():
    d, clock = clocked_device(real_time_factor=1.0)
    dt = d.sim.dt
    clock.now = 10 * dt                   # ten steps of wall time at real time (stepping itself takes none)
    d.advance(budget=1e9, tick_period=0.02)
    assert d.sim.steps == 10 and d.sim_time == pytest.approx(10 * dt)
    d.pause(True)
    clock.now += 10 * dt
    d.advance(budget=1e9, tick_period=0.02)
    assert d.sim.steps == 10
    d.pause(False)                        # the schedule restarts at the present: the paused time is not owed
    clock.now += 5 * dt
    d.advance(budget=1e9, tick_period=0.02)
    assert d.sim.steps == 15


def test_a_failed_step_keeps_the_state_is_reported_once_and_clears(monkeypatch):
    from flagbot_sim.physics import StepFailed
    d, clock = clocked_device()
    real_step = d.sim.step
    state = d.sim.state

    def failing_step(*a, **k):
        raise StepFailed("Newton did not converge at t = 0")
    monkeypatch.setattr(d.sim, "step", failing_step)
    told = []
    clock.now = 0.05
    d.advance(budget=1e9, tick_period=0.02, on_failure=told.append)
    assert told == ["Newton did not converge at t = 0"] and d.step_failures == 1
    assert d.sim.state is state                        # the last good state stays
    errors, _ = d.problems(float("nan"))
    assert errors == ["1 step failure since the last report (1 in total), keeping the last good state: "
                      "Newton did not converge at t = 0"]
    monkeypatch.setattr(d.sim, "step", real_step)
    clock.now = 0.1
    d.advance(budget=1e9, tick_period=0.02)
    assert d.sim.steps > 0 and d.problems(float("nan"))[0] == []       # a good step since: no error any more


def test_a_non_finite_state_is_withheld_and_counted():
    d, _ = clocked_device()
    assert d.observe() is not None and d.withheld == 0
    d.sim.state.q[0] = math.nan
    assert d.observe() is None and d.withheld == 1
    assert d.problems(float("nan"))[0] == ["non-finite state withheld from publication"]


def test_a_rejected_command_is_counted():
    d, _ = clocked_device()
    d.command(math.nan)
    d.command(1e6)
    d.command(1.0)
    assert d.rejected == 2
