"""Recording from sim_node, re-simulation of recordings, and the sample recordings shipped in bags/."""
import re
import tomllib
from pathlib import Path

import pytest
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64
from std_srvs.srv import SetBool

from flagbot_sim.bag import BagReader
from flagbot_sim.runs.summary import summarize
from flagbot_sim.runs.resim import resimulate
from flagbot_sim.scene import load_scene

from ros_helpers import DISCOVERY_TIMEOUT, EVENT_TIMEOUT, NodeProcess, call, set_params, spin_until

BAGS = Path(__file__).resolve().parents[1] / "bags"
#: the sample recordings bags/README.md describes (a table row each): every one of them must be committed
DESCRIBED = re.findall(r"^\| `([^`/]+\.mcap)` \|", (BAGS / "README.md").read_text(), re.MULTILINE)
SAMPLES = [BAGS / name for name in DESCRIBED]
#: re-simulation tolerance stated in msg_docs/record_replay.md: Newton's tolerance, seen through the
#: per-step rates (a displacement error divided by dt)
RESIM_POSITION_TOL = 1e-8      # m
RESIM_RATE_TOL = 1e-5          # rad/s


@pytest.fixture
def probe(ros):
    """The module's probe node; the subscriptions, publishers and clients a test adds to it are destroyed when the
    test ends, so that later tests' spins do not keep serving (and decoding) them."""
    before = set(ros.subscriptions) | set(ros.publishers) | set(ros.clients)
    yield ros
    for sub in set(ros.subscriptions) - before:
        ros.destroy_subscription(sub)
    for pub in set(ros.publishers) - before:
        ros.destroy_publisher(pub)
    for cli in set(ros.clients) - before:
        ros.destroy_client(cli)


def run_recording_node(ros, tmp_path, record_at_launch=True, overrides=()):
    out = tmp_path / "run.mcap"
    over = ", ".join(f'"{o}"' for o in ("flagellum.length=0.05", *overrides))
    args = ["--ros-args", "-p", "scene:=design2", "-p", "n_flagella:=3",
            "-p", f"scene_overrides:=[{over}]", "-p", "real_time_factor:=4.0",
            "-p", "start_paused:=true", "-p", "initial_omega:=6.0"]
    if record_at_launch:
        args += ["-p", f"record:={out}"]
    proc = NodeProcess("flagbot_sim.ros.sim_node", *args)
    clock = []
    ros.create_subscription(Clock, "/clock", lambda m: clock.append(m.clock.sec + 1e-9 * m.clock.nanosec), 10)
    spin_until(ros, lambda: clock, DISCOVERY_TIMEOUT, "/clock")
    if not record_at_launch:
        (res,) = set_params(ros, "sim_node", record=str(out))
        assert res.successful, res.reason
    cmd = ros.create_publisher(Float64, "cmd_omega", 10)
    # two subscriptions: sim_node's command input and its recorder (which subscribes once it sees a publisher)
    spin_until(ros, lambda: cmd.get_subscription_count() >= 2, DISCOVERY_TIMEOUT, "cmd_omega input and recorder")
    call(ros, ros.create_client(SetBool, "/sim_node/pause"), SetBool.Request(data=False))   # ~/pause
    spin_until(ros, lambda: clock and clock[-1] > 1.0, EVENT_TIMEOUT, "1 s of simulation")
    cmd.publish(Float64(data=9.0))                        # a command change during the recording
    spin_until(ros, lambda: clock[-1] > 2.5, EVENT_TIMEOUT, "2.5 s of simulation")
    return proc, out


@pytest.mark.parametrize("at_launch", [True, False])
def test_sim_node_records_a_run_that_re_simulates_exactly(probe, tmp_path, at_launch):
    proc, out = run_recording_node(probe, tmp_path, record_at_launch=at_launch)
    code, log = proc.stop()
    assert code == 0 and "Traceback" not in log and "rosout" not in log, log
    with BagReader(out) as r:
        assert r.report.ok, r.report.describe_loss()
        topics = set(r.topics)
        meta = r.run_metadata()
    assert {"/clock", "/joint_states", "/head_pose", "/odom", "/speed", "/cmd_omega", "/tf", "/tf_static"} <= topics
    # the metadata alone rebuilds the node's scene: file + overrides + n_flagella
    expected = load_scene("design2", ["flagellum.length=0.05", "robot.n_flagella=3"])
    assert tomllib.loads(meta.scene_toml) == tomllib.loads(expected.to_toml())
    assert meta.parameters["n_flagella"] == 3 and meta.parameters["initial_omega"] == 6.0
    res = resimulate(out)
    assert [w for _, w in res.commands][-1] == 9.0 and len(res.commands) >= 2
    assert res.max_position_error == 0.0 and res.max_omega_h_error == 0.0 and res.max_omega_t_error == 0.0
    assert res.samples > 10 and not res.notes


def test_error_controlled_live_run_re_simulates_exactly(probe, tmp_path):
    """With time.rtol set, sim_node takes the steps the error control picks (never cut to its ticks), so the
    recording's re-simulation takes the same steps and reproduces the run exactly, command change included; and
    simulated time on /clock only grows."""
    proc, out = run_recording_node(probe, tmp_path, overrides=("time.integrator='bdf2'", "time.rtol=1e-3"))
    code, log = proc.stop()
    assert code == 0 and "Traceback" not in log, log
    with BagReader(out) as r:
        clock = [m.clock.sec + 1e-9 * m.clock.nanosec for _, _, m in r.decoded_many(["/clock"])["/clock"]]
    assert clock == sorted(clock) and clock[-1] > 2.5
    res = resimulate(out)
    assert [w for _, w in res.commands][-1] == 9.0
    assert res.max_position_error == 0.0 and res.max_omega_h_error == 0.0 and res.max_omega_t_error == 0.0
    assert res.samples > 10 and not res.notes, res.notes
    # and the steps really were the controller's: not multiples of time.dt
    scene = load_scene("design2", ["flagellum.length=0.05", "robot.n_flagella=3", "time.integrator='bdf2'",
                                   "time.rtol=1e-3"])
    from flagbot_sim.physics import Simulation
    sim = Simulation(scene)
    sim.set_omega(6.0)
    sizes = {round(sim.step().substep_dts[0], 12) for _ in range(20)}
    assert len(sizes) > 3


def test_sim_node_killed_at_the_worst_moment_loses_at_most_a_quarter_second_of_its_recording(tmp_path):
    """sim_node recording with record:= at real-time factor 1, killed with SIGKILL just before its recorder's next
    flush was due: `flagbot bag-recover` gives back every simulated second up to within 0.25 s of what it had
    published on /clock (docs/recording.md quotes this measurement; tests/crash_loss.py runs it many times)."""
    import crash_loss
    kill = crash_loss.measure("sim_node", "worst", tmp_path)
    print("kill -9:", kill.line())
    assert kill.since_flush >= kill.period - 3 * crash_loss.MARGIN and kill.period < 0.2, kill.line()
    assert kill.loss <= 0.25, kill.line()
    with BagReader(kill.recovered_path) as r:       # the recovered file is complete and still re-simulates
        assert r.report.ok and r.run_metadata().scene_toml
    res = resimulate(kill.recovered_path)
    assert res.reproduced and res.samples > 10, res.verdict()


def test_record_parameter_refuses_an_existing_file(ros, tmp_path):
    existing = tmp_path / "taken.mcap"
    existing.write_bytes(b"keep me")
    proc = NodeProcess("flagbot_sim.ros.sim_node", "--ros-args", "-p", "scene:=design2", "-p", "start_paused:=true")
    try:
        spin_until(ros, lambda: "sim_node" in ros.get_node_names(), DISCOVERY_TIMEOUT, "sim_node")
        (res,) = set_params(ros, "sim_node", record=str(existing))
        assert not res.successful and "taken.mcap" in res.reason
        assert existing.read_bytes() == b"keep me"
    finally:
        code, log = proc.stop()
    assert code == 0, log


def test_the_sample_recordings_are_committed_and_described():
    """A missing sample fails here (and in its own test_sample_recordings case) instead of being skipped."""
    assert DESCRIBED, "bags/README.md describes no sample recording"
    assert sorted(p.name for p in BAGS.glob("*.mcap")) == sorted(DESCRIBED)


@pytest.mark.parametrize("bag", SAMPLES, ids=lambda p: p.name)
def test_sample_recordings(bag):
    from mcap_ros2.reader import read_ros2_messages
    from rosbags.highlevel import AnyReader
    assert bag.stat().st_size < 5 * 2 ** 20
    assert bag.name in (BAGS / "README.md").read_text(), "every sample is described in bags/README.md"
    with BagReader(bag) as r:
        assert r.report.ok
        count = r.report.messages
    # two independent readers see the same messages
    assert sum(1 for _ in read_ros2_messages(str(bag))) == count
    with AnyReader([bag]) as ar:
        n = 0
        for conn, _, raw in ar.messages():
            ar.deserialize(raw, conn.msgtype)
            n += 1
    assert n == count
    # the recording re-simulates to solver tolerance (exactly with the version that recorded it; a later solver
    # stops its Newton iterations at other points inside the tolerance), and its steps are steady with
    # omega_h + omega_t = omega_T
    res = resimulate(bag)
    assert res.max_position_error <= RESIM_POSITION_TOL
    assert max(res.max_omega_h_error, res.max_omega_t_error) <= RESIM_RATE_TOL
    # ... over the whole recording: every sample compared (a reversal is a command, not a reset)
    assert res.status == "REPRODUCED" and res.complete and res.fraction == 1.0, res.verdict()
    assert res.compared_samples == res.samples - 1 and not res.uncompared
    s = summarize(bag)
    steps = [st for st in s["steps"] if st["omega_T"] != 0.0]
    assert len(steps) >= 2
    for st in steps:
        assert st["omega_h"] + st["omega_t"] == pytest.approx(st["omega_T"], rel=0.01)
        assert st["v"] > 0
