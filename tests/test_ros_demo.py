"""`flagbot demo` runs in the ROS domain the user exported (or the one given with --domain), else one of its own.

The full demo (three nodes, a minute of simulated time) is the main job (`python3 dev.py run`); here only the
choice of domain, through the function and through the real command line."""
import math

import pytest

from flagbot_sim.ros.demo import demo_domain

from cli_helpers import flagbot


def test_domain_comes_from_the_option_then_the_environment_then_the_pid():
    assert demo_domain(7, {"ROS_DOMAIN_ID": "42"}, pid=12345) == 7
    assert demo_domain(None, {"ROS_DOMAIN_ID": "42"}, pid=12345) == 42
    assert demo_domain(None, {"ROS_DOMAIN_ID": " 0 "}, pid=12345) == 0
    assert demo_domain(None, {}, pid=12345) == 145
    assert demo_domain(None, {"ROS_DOMAIN_ID": ""}, pid=12345) == 145      # exported but empty: unset
    for bad in ("abc", "233", "-1", "1.5"):
        with pytest.raises(ValueError, match="ROS_DOMAIN_ID"):
            demo_domain(None, {"ROS_DOMAIN_ID": bad}, pid=1)
    with pytest.raises(ValueError, match="--domain"):
        demo_domain(300, {}, pid=1)


def test_the_command_reads_the_exported_domain(monkeypatch):
    # an exported id the demo would use is checked before any node starts: a bad one is a one-line refusal
    monkeypatch.setenv("ROS_DOMAIN_ID", "999")
    r = flagbot("demo", "--step-duration", "0.1", timeout=120)
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.strip() == "error: ROS_DOMAIN_ID = 999 is out of range: a ROS domain id is 0-232"


def test_the_step_table_takes_the_beam_prediction_whose_split_is_the_steps_command():
    """beam_node re-publishes its last prediction while it solves for the next command, so a value tagged with
    the new command can be the old prediction (before: a 0.0000 row for every step of a short demo); the one
    for a step is the one whose omega_h + omega_t equals the step's omega_T, whenever it arrived."""
    from flagbot_sim.ros.demo import step_table
    samples = {k: [(t, 1.0) for t in (1.0, 1.9, 3.0, 3.9)] for k in ("omega_h", "omega_t", "v")}
    beam = [(0.5, 5.0, (0.0, 0.0, 0.0)),            # stale: the prediction for omega_T = 0, tagged with 5
            (2.5, 10.0, (4.8, 0.2, 1e-4)),          # the 5 rad/s prediction, arriving during the next step
            (3.5, 10.0, (9.5, 0.5, 2e-4))]
    rows = step_table(samples, [(0.0, 2.0, 5.0), (2.0, 4.0, 10.0), (4.0, 6.0, 20.0)], beam)
    assert [(r["beam_omega_h"], r["beam_v"]) for r in rows[:2]] == [(4.8, 1e-4), (9.5, 2e-4)]
    assert math.isnan(rows[2]["beam_omega_h"]) and math.isnan(rows[2]["omega_h"])


# ------------------------------------------------------------------------------------------------ start-up
import json  # noqa: E402
import os  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import textwrap  # noqa: E402

from cli_helpers import ROOT  # noqa: E402
from flagbot_sim.ros.demo import Liveness, start_phase  # noqa: E402

#: s the test's sitecustomize holds sim_node back: past the 60 s the demo used to allow for the nodes to appear
SIM_NODE_DELAY = 65.0


def _sitecustomize(directory, body: str):
    """A sitecustomize.py that runs ``body`` in sim_node's process only (found by its command line: sys.argv is
    not set yet when sitecustomize runs), on a PYTHONPATH of the test's own: nothing in the product knows of it."""
    directory.mkdir()
    (directory / "sitecustomize.py").write_text(textwrap.dedent('''\
        import os, sys, time
        with open("/proc/self/cmdline", "rb") as _f:
            _argv = _f.read().split(b"\\0")
        if b"flagbot_sim.ros.sim_node" in _argv:
        ''') + textwrap.indent(textwrap.dedent(body), "    "))
    return directory


def _demo(tmp_path, sitecustomize, *args, env_extra=None, timeout=1500):
    env = dict(os.environ, PYTHONPATH=f"{sitecustomize}{os.pathsep}{ROOT}", **(env_extra or {}))
    return subprocess.run([sys.executable, "-m", "flagbot_sim", "demo", "--log-dir", str(tmp_path / "logs"),
                           *args], capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout)


def test_the_demo_waits_for_a_cold_slow_start_and_keeps_every_nodes_log(tmp_path):
    """An empty kernel cache and a sim_node held back 65 s before Python even imports it (longer than the fixed
    60 s the demo used to give the nodes, compile included): the demo compiles the kernels first, as a step of its
    own, waits for sim_node's readiness while saying what it waits for, and completes with the table."""
    sc = _sitecustomize(tmp_path / "slow", f'''\
        print("test: sim_node held back {SIM_NODE_DELAY:g} s", file=sys.stderr, flush=True)
        time.sleep({SIM_NODE_DELAY!r})
        ''')
    cache = tmp_path / "numba_cache"            # empty: every kernel is compiled
    # (at most 4x real time: a fast machine would otherwise be through the 6 s step between two publications)
    r = _demo(tmp_path, sc, "--rpm", "100", "--step-duration", "6", "--real-time-factor", "4", "--json",
              env_extra={"NUMBA_CACHE_DIR": str(cache)})
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "error:" not in r.stderr
    (row,) = json.loads(r.stdout)["steps"]
    # a real run: the head turns with most of omega_T and the robot swims head first (design 1, 100 rpm)
    assert row["omega_T"] == pytest.approx(100 * math.pi / 30)
    assert 0.5 * row["omega_T"] < row["omega_h"] < row["omega_T"] and row["v"] > 0
    # the compile was its own step, before the nodes: sim_node started warm and compiled nothing
    assert "demo: compiling kernels (first run only" in r.stderr and "demo: kernels compiled in" in r.stderr
    assert any(cache.rglob("*.nbi"))
    logs = {p.stem: p.read_text() for p in (tmp_path / "logs").glob("*.log")}
    assert set(logs) == {"sim_node", "beam_node", "cmd_profile"}
    assert "compiling kernels" not in logs["sim_node"]
    # the delay happened in sim_node, and only there; its log is kept, up to its readiness line
    assert f"test: sim_node held back {SIM_NODE_DELAY:g} s" in logs["sim_node"]
    assert not any("held back" in logs[k] for k in ("beam_node", "cmd_profile"))
    assert "waiting for cmd_omega" in logs["sim_node"]
    # while it waited it said for what; it was ready no sooner than the delay allows
    waiting = [line for line in r.stderr.splitlines() if line.startswith("waiting for the nodes:")]
    assert waiting and all("sim_node: " in line for line in waiting)
    assert any("sim_node: starting" in line and "beam_node: ready" in line for line in waiting)
    (ready,) = [line for line in r.stderr.splitlines() if line.startswith("nodes ready after ")]
    from flagbot_sim.progress import format_duration
    assert ready >= f"nodes ready after {format_duration(SIM_NODE_DELAY)}"   # '1m05s' .. '1m59s' sort as times


def test_a_node_that_dies_at_start_is_one_error_line_with_its_log(tmp_path):
    """sim_node ends before it is ready: one `error:` line naming it, its exit code and its kept log, then the
    log's last lines (which say why); exit status 1, no traceback, and the other nodes are stopped."""
    sc = _sitecustomize(tmp_path / "dies", '''\
        print("test: sim_node gives up at start", file=sys.stderr, flush=True)
        os._exit(3)
        ''')
    r = _demo(tmp_path, sc, "--rpm", "100", "--step-duration", "2", timeout=600)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and r.stdout == ""
    errors = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    log = tmp_path / "logs" / "sim_node.log"
    assert errors == [f"error: sim_node ended with exit code 3 before it was ready (its log: {log})"]
    tail = r.stderr.split(errors[0], 1)[1]
    assert "last 1 lines of sim_node's log:\n  | test: sim_node gives up at start" in tail
    assert log.read_text() == "test: sim_node gives up at start\n"


def test_the_liveness_rule_fails_only_a_node_that_stopped_working_or_took_far_too_long():
    live = Liveness(start=0.0, limit=600.0, stall=60.0, factor=3)
    # within the limit nothing fails, working or not
    for t in range(0, 601, 10):
        live.observe(float(t), (0.0, 0))
        assert live.verdict(float(t)) is None
    # past it: a node that keeps using CPU is waited for ...
    for t in range(610, 1800, 10):
        live.observe(float(t), (float(t), 0))
        assert live.verdict(float(t)) is None
    # ... up to 3x the limit
    live.observe(1810.0, (1810.0, 0))
    assert "1810 s (3 x --start-timeout 600 s), though still working" in live.verdict(1810.0)
    # a node past the limit with no sign of work for 60 s has failed; output counts as work as much as CPU time
    idle = Liveness(start=0.0, limit=600.0, stall=60.0)
    idle.observe(0.0, (5.0, 100))
    idle.observe(580.0, (5.0, 180))                     # wrote a line at 580 s
    assert idle.verdict(639.0) is None                  # 59 s idle
    assert idle.verdict(640.0) == ("not ready after 640 s, and no sign of work (no CPU time used, no output) "
                                   "for the last 60 s")
    # a short limit shortens the stall window with it
    assert Liveness(start=0.0, limit=5.0).stall == 5.0


def test_the_status_says_what_each_node_is_doing_from_its_log():
    assert start_phase("sim_node", "", ready=False) == "starting"
    assert start_phase("sim_node", "flagbot_sim: compiling kernels (first run only, ...)\n", ready=False) == \
        "compiling kernels (first run only)"
    log = "flagbot_sim: compiling kernels (first run only)\n[INFO] [sim_node]: ... waiting for cmd_omega\n"
    assert start_phase("sim_node", log, ready=False) == "started, connecting"
    assert start_phase("sim_node", log, ready=True) == "ready"
    assert start_phase("beam_node", "anything", ready=False) == "starting"


def test_the_demo_takes_a_beam_prediction_only_whole_whatever_order_its_three_topics_deliver_in():
    """beam_node publishes speed, omega_h, omega_t at each tick on depth-1 queues; the monitor takes them in any
    order the executor picks. Every prediction it confirms must be one tick's three values, never a mix (a mix
    once put 150 rpm's speed beside 100 rpm's split), and a prediction that stays is confirmed."""
    import random
    from flagbot_sim.ros.demo import BeamConfirm
    order = ("v", "h", "t")
    for seed in range(300):
        rng = random.Random(seed)
        preds = [(float(k), 10.0 + k, 100.0 + k) for k in range(4)]     # (h, t, v) of each command
        slot = {}                                                        # topic -> unread value (depth 1)
        confirm, got = BeamConfirm(), []
        for tick in range(60):
            h, t, v = preds[min(tick // 15, 3)]
            for key, value in zip(order, (v, h, t)):
                slot[key] = value                                        # the newer message replaces the unread one
                while slot and rng.random() < 0.5:                       # the executor takes some, in any order
                    k = rng.choice(sorted(slot))
                    snap = confirm.feed(k, slot.pop(k))
                    if snap is not None:
                        got.append(snap)
        for k in sorted(slot):
            snap = confirm.feed(k, slot.pop(k))
            if snap is not None:
                got.append(snap)
        assert set(got) <= set(preds), (seed, set(got) - set(preds))
        assert preds[-1] in got, seed


def test_the_demo_asks_each_node_to_stop_once(tmp_path):
    """A node takes a second SIGINT as "stop now" (its recording then loses its end: a sample recording was cut
    this way, a KeyboardInterrupt inside the recorder's close). The demo's stop sends one, however called."""
    import signal
    import time
    from flagbot_sim.ros.demo import NodeProcess
    code = textwrap.dedent("""
        import signal, sys, time
        got = []
        signal.signal(signal.SIGINT, lambda *a: got.append(1))
        print("ready", flush=True)
        while not got:
            time.sleep(0.01)
        time.sleep(1.0)                  # an orderly stop takes a while; count what arrives meanwhile
        sys.exit(len(got))
    """)
    node = NodeProcess("counter", [sys.executable, "-c", code], tmp_path / "counter.log", dict(os.environ))
    deadline = time.monotonic() + 60
    while "ready" not in node.log() and time.monotonic() < deadline:
        time.sleep(0.02)
    node.interrupt()                     # what the demo's teardown does for every node, then stop() for each
    assert node.stop(timeout=60) == 1, node.log()
