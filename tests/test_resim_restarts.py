"""`replay --resimulate` on live sim_node recordings covers the whole recording or says it does not.

A command reversal or a square wave through zero is a command: the motor angle turns back, and the whole
recording is compared. A `~/reset` call and a rebuild (a new scene_overrides value) are recorded on `resets`
(latched, so a recorder started later still has the last one) and the comparison goes on across them from the
robot's initial state. The same recording without that topic shows the reset only as a jump of the motor angle
that no command can make: the verdict is PARTIAL, with the compared duration, and the exit code 1.
"""
import json

import numpy as np
import pytest
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from flagbot_sim.bag import BagReader, BagWriter, qos_to_yaml
from flagbot_sim.runs.resim import motor_samples, resimulate

from cli_helpers import flagbot
from ros_helpers import DISCOVERY_TIMEOUT, NodeProcess, call, set_params, spin_until
from test_recording import probe  # noqa: F401  (the fixture)

#: a short robot at 4x real time: seconds of simulated time cost little wall time, and the 50 Hz samples stay
#: dense (0.08 s of simulated time apart) when the machine keeps up
NODE_ARGS = ["-p", "scene:=design2", "-p", "n_flagella:=2", "-p", 'scene_overrides:=["flagellum.length=0.05"]',
             "-p", "real_time_factor:=4.0", "-p", "start_paused:=true"]


def drive(ros, tmp_path, actions, record_at_launch=True):
    """Run sim_node through ``actions`` (("cmd", omega), ("wait", simulated seconds), ("reset",),
    ("record",) to start the recording now, ("set", {name: value})), then 0.5 s more of simulation so that the
    last command is in the recording for several samples, and stop it with SIGINT; the recording's path."""
    out = tmp_path / "run.mcap"
    proc = NodeProcess("flagbot_sim.ros.sim_node", "--ros-args", *NODE_ARGS,
                       *(["-p", f"record:={out}"] if record_at_launch else []))
    clock = []
    ros.create_subscription(Clock, "/clock", lambda m: clock.append(m.clock.sec + 1e-9 * m.clock.nanosec), 10)
    cmd = ros.create_publisher(Float64, "cmd_omega", 10)
    reset = ros.create_client(Trigger, "/sim_node/reset")
    recorders = 1 + record_at_launch          # sim_node's command input (+ its recorder's subscription)

    def subscribed():
        # the recorder subscribes to every topic in one graph poll: its cmd_omega subscription means it is there
        spin_until(ros, lambda: cmd.get_subscription_count() >= recorders, DISCOVERY_TIMEOUT,
                   "cmd_omega input" + (" and recorder" if recorders > 1 else ""))
    try:
        spin_until(ros, lambda: clock, DISCOVERY_TIMEOUT, "/clock")
        subscribed()
        call(ros, ros.create_client(SetBool, "/sim_node/pause"), SetBool.Request(data=False))
        for action in [*actions, ("wait", 0.5)]:
            if action[0] == "cmd":
                cmd.publish(Float64(data=float(action[1])))
            elif action[0] == "wait":
                end = clock[-1] + action[1]
                spin_until(ros, lambda: clock[-1] >= end, 120, f"{action[1]} s of simulation")
            elif action[0] == "reset":
                assert call(ros, reset, Trigger.Request()).success
            elif action[0] == "record":
                (res,) = set_params(ros, "sim_node", record=str(out))
                assert res.successful, res.reason
                recorders = 2
                subscribed()
            elif action[0] == "set":
                for res in set_params(ros, "sim_node", **action[1]):
                    assert res.successful, res.reason
    finally:
        code, log = proc.stop()
    assert code == 0 and "Traceback" not in log, log
    return out


def recorded_motor(path):
    with BagReader(path) as r:
        assert r.report.ok, r.report.describe_loss()
        js = [m for _, _, m in r.decoded("/joint_states")]
    return motor_samples(js)


def changes(values):
    """The values in order with repeats dropped: the command sequence."""
    out = []
    for v in values:
        if not out or out[-1] != v:
            out.append(v)
    return out


def assert_whole_and_exact(res, path):
    """Every recorded sample compared and the motion identical (same version: exactly 0 difference)."""
    assert res.status == "REPRODUCED" and res.reproduced, res.verdict()
    assert res.complete and res.fraction == 1.0 and not res.uncompared
    assert res.compared_duration == res.recorded_duration
    _, t, _, _ = recorded_motor(path)
    assert res.recorded_duration == pytest.approx(t[-1] - t[0], abs=1e-12)
    assert res.max_position_error == 0.0 and res.max_omega_h_error == 0.0 and res.max_omega_t_error == 0.0
    cli = flagbot("replay", str(path), "--resimulate", "--json")
    assert cli.returncode == 0, cli.stdout + cli.stderr
    got = json.loads(cli.stdout)
    assert got["status"] == "REPRODUCED" and got["fraction"] == 1.0 and got["complete"] is True
    assert got["compared_duration"] == got["recorded_duration"] == res.recorded_duration
    assert "(100.0 %" in got["verdict"]


@pytest.mark.parametrize("sent", [[10.0, -10.0, 10.0], [8.0, 0.0, -8.0, 0.0, 8.0, -8.0]],
                         ids=["reversals", "square_wave_through_zero"])
def test_a_command_that_changes_sign_is_a_command_and_the_whole_recording_is_compared(probe, tmp_path, sent):
    hold = 1.5 if len(sent) == 3 else 0.4
    actions = [a for w in sent for a in (("cmd", w), ("wait", hold))]
    out = drive(probe, tmp_path, actions)
    _, t, angle, rate = recorded_motor(out)
    # the recording really turns the motor back: what the old rule took for a reset at the first reversal
    assert np.any(np.diff(angle) * np.sign(rate[:-1] + 1e-300) < -1e-9)
    assert t[-1] - t[0] >= hold * len(sent)
    res = resimulate(out)
    assert changes([w for _, w in res.commands])[-len(sent):] == sent
    assert res.restarts == [] and res.parts == 1
    assert_whole_and_exact(res, out)
    print(res.verdict())


def stripped(src, dst, topic):
    """A copy of a recording without one topic."""
    with BagReader(src) as r:
        keep = [t for t in r.topics if t != topic]
        assert len(keep) == len(r.topics) - 1
        with BagWriter(dst, metadata=r.run_metadata()) as w:
            for t in keep:
                info = r.topics[t]
                w.add_topic(t, info.type_name, offered_qos_profiles=qos_to_yaml(info.offered_qos))
            for m in r.messages(keep):
                w.write(m.topic, m.data, m.log_time_ns, m.publish_time_ns)
    return dst


def test_a_reset_and_a_rebuild_are_recorded_and_compared_across(probe, tmp_path):
    out = drive(probe, tmp_path, [("cmd", 10.0), ("wait", 1.0), ("reset",), ("wait", 0.5), ("cmd", -10.0),
                                  ("wait", 1.0), ("set", {"scene_overrides": ["flagellum.length=0.04"]}),
                                  ("wait", 0.5), ("cmd", 5.0), ("wait", 0.5)])
    with BagReader(out) as r:
        info = r.topics["/resets"]
        assert info.type_name == "diagnostic_msgs/msg/DiagnosticArray" and info.count == 2
        assert [q.durability for q in info.offered_qos] == ["transient_local"]
    _, t, angle, _ = recorded_motor(out)
    res = resimulate(out)
    assert [r["cause"] for r in res.restarts] == ["reset", "rebuild"] and res.parts == 3
    reset_t, rebuild_t = (r["t"] for r in res.restarts)
    assert t[0] < reset_t < rebuild_t < t[-1]
    # the reset put the motor back at 0: the first sample after it is within one interval's turn of 0
    k = int(np.searchsorted(t, reset_t, side="right"))
    assert abs(angle[k]) <= 10.0 * (t[k] - reset_t) + 1e-9 and abs(angle[k - 1]) > 5.0
    assert [r["omega_T"] for r in res.restarts] == [10.0, -10.0]       # the command is kept through each
    assert changes([w for _, w in res.commands])[-3:] == [10.0, -10.0, 5.0]
    assert res.compared_samples == res.samples - 1        # all but the initial state at t = 0
    assert_whole_and_exact(res, out)

    # the same recording without its record of the restarts: the reset shows as a jump no command can make
    blind = stripped(out, tmp_path / "no_resets.mcap", "/resets")
    res = resimulate(blind)
    assert res.status == "PARTIAL" and not res.reproduced and not res.complete, res.verdict()
    assert res.compared_duration == pytest.approx(t[k - 1] - t[0], abs=1e-9)
    assert res.fraction == pytest.approx((t[k - 1] - t[0]) / (t[-1] - t[0]), rel=1e-9) and res.fraction < 1
    assert any("jumps" in why and "no resets topic" in why for why in res.uncompared)
    cli = flagbot("replay", str(blind), "--resimulate", "--json")
    assert cli.returncode == 1, cli.stdout + cli.stderr
    got = json.loads(cli.stdout)
    assert got["status"] == "PARTIAL" and got["reproduced"] is False and got["verdict"].startswith("verdict: PARTIAL")
    text = flagbot("replay", str(blind), "--resimulate")
    assert text.returncode == 1 and text.stdout.strip().splitlines()[-1].startswith(
        f"verdict: PARTIAL: compared only {res.compared_duration:.3f} s of the {res.recorded_duration:.3f} s")


def test_a_recording_started_after_a_reset_starts_from_it(probe, tmp_path):
    """The resets topic is latched: sim_node's recorder, started after the reset, still gets it and the
    re-simulation starts from that restart (not from t = 0 with commands it never saw)."""
    out = drive(probe, tmp_path, [("cmd", 10.0), ("wait", 1.0), ("reset",), ("wait", 0.3), ("record",),
                                  ("cmd", -10.0), ("wait", 1.0)], record_at_launch=False)
    _, t, _, _ = recorded_motor(out)
    res = resimulate(out)
    assert [r["cause"] for r in res.restarts] == ["reset"] and res.restarts[0]["t"] < t[0]
    assert res.parts == 1 and res.restarts[0]["omega_T"] == 10.0
    assert_whole_and_exact(res, out)
