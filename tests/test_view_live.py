"""The Foxglove live view, seen by a real WebSocket client on 127.0.0.1 (tests/foxglove_client.py).

What a Foxglove app would see: the server's info and channels, then, once subscribed, a scene whose flagellum points
are the simulation's node positions in the world frame at their true radius, the world -> head transform of the
published head pose, and the plotted numbers of the snapshot sim_node publishes.
"""
import asyncio
import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from cli_helpers import ROOT
from foxglove_client import Client
from view_testlib import stepped_design2

from flagbot_sim import world
from flagbot_sim.view import geometry, layout, live
from flagbot_sim.view.live import TOPICS, LiveView, ViewError


@pytest.fixture(scope="module")
def sim():
    return stepped_design2(3)


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, 30))


async def subscribed(view: LiveView, topics=None) -> Client:
    c = await Client.connect(view.url)
    await c.subscribe(topics)
    for _ in range(500):
        if view.has_clients():
            return c
        await asyncio.sleep(0.01)
    raise AssertionError("the server never saw the subscription")


def pts(p) -> list:
    return [p["x"], p["y"], p["z"]]


def test_a_client_sees_the_channels_and_decodes_the_robot_at_the_simulated_node_positions(sim):
    snap = sim.snapshot()
    with LiveView(port=0) as view:
        async def scenario():
            c = await subscribed(view)
            assert c.server_info["op"] == "serverInfo" and "time" in c.server_info["capabilities"]
            adv = c.topics()
            assert set(adv) == set(TOPICS)
            assert adv["/flagbot/scene"]["schemaName"] == "foxglove.SceneUpdate"
            assert adv["/tf"]["schemaName"] == "foxglove.FrameTransforms"
            assert adv["/flagbot/state"]["encoding"] == "json"
            assert set(json.loads(adv["/flagbot/state"]["schema"])["properties"]) >= {
                "omega_T", "omega_h", "omega_t", "v", "motor_torque"}
            assert view.update(sim) is True
            got = await c.collect(set(TOPICS))
            await c.close()
            return got
        got = run(scenario())
    t_ns = int(round(sim.time * 1e9))
    assert all(lt == t_ns for rows in got.values() for lt, _ in rows), "log time = simulated time"
    entities = {e["id"]: e for e in got["/flagbot/scene"][0][1]["entities"]}
    assert set(entities) == {"head", "plate", "flagellum/0", "flagellum/1", "flagellum/2"}
    sc = sim.scene
    for i, nodes in enumerate(sim.flagella_centrelines()):
        line = entities[f"flagellum/{i}"]["lines"][0]
        # the node positions in the world frame (REP 103: sim frame turned by pi about z, origin = head at rest)
        np.testing.assert_array_equal([pts(p) for p in line["points"]], world.to_world(nodes, sim.observer.origin))
        assert line["thickness"] == 2 * sc.flagellum.radius and line["scale_invariant"] is False
        assert entities[f"flagellum/{i}"]["frame_id"] == "world"
    # the head where sim_node's head_pose puts it, with its radius; the plate disc of radius R_d
    head = entities["head"]["spheres"][0]
    np.testing.assert_allclose(pts(head["pose"]["position"]), snap.position, rtol=0, atol=1e-15)
    assert head["size"]["x"] == 2 * sc.head.radius
    # (the plate arms are stiff, not rigid: the drawn disc is their current length, within 1e-7 of R_d)
    assert entities["plate"]["cylinders"][0]["size"]["x"] == pytest.approx(2 * sc.R_d, rel=1e-6)
    # world -> head is the published pose
    tf = got["/tf"][0][1]["transforms"][0]
    assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("world", "head")
    np.testing.assert_allclose(pts(tf["translation"]), snap.position, rtol=0, atol=1e-15)
    q = tf["rotation"]
    np.testing.assert_allclose([q["x"], q["y"], q["z"], q["w"]], snap.orientation, rtol=0, atol=1e-12)
    # the plotted numbers are the snapshot's, exactly (JSON floats round-trip)
    state = got["/flagbot/state"][0][1]
    for k in ("omega_h", "omega_t", "omega_T", "v", "motor_torque", "t"):
        assert state[k] == getattr(snap, k), k
    assert snap.omega_h != 0 and snap.motor_torque != 0
    # the tube wall: the paper's container, 53 mm inner radius, along x
    tube = got["/flagbot/tube"][0][1]["entities"][0]["cylinders"][0]
    assert tube["size"]["x"] == pytest.approx(0.106)


def test_nothing_is_built_without_a_subscriber_and_publications_are_rate_limited(sim, monkeypatch):
    built = []
    real = geometry.RobotGeometry.from_simulation.__func__
    monkeypatch.setattr(geometry.RobotGeometry, "from_simulation",
                        classmethod(lambda cls, *a, **k: built.append(1) or real(cls, *a, **k)))
    with LiveView(port=0, max_rate=4.0) as view:
        assert not view.has_clients()
        assert [view.update(sim) for _ in range(50)] == [False] * 50
        assert built == [], "no geometry may be built while nobody watches"

        async def scenario():
            c = await subscribed(view, {"/flagbot/state"})
            first = view.update(sim)                    # a new subscriber is served at once
            burst = [view.update(sim) for _ in range(50)]
            await asyncio.sleep(0.3)                    # > 1 / max_rate
            later = view.update(sim)
            got = []
            while len(got) < 2:
                got.append(await c.receive())
            with pytest.raises(asyncio.TimeoutError):   # and nothing else was sent
                await c.receive(timeout=0.3)
            await c.close()
            return first, burst, later, got
        first, burst, later, got = run(scenario())
    assert first is True and not any(burst) and later is True
    assert len(built) == 2 and view.published == 2
    assert [topic for topic, _, _ in got] == ["/flagbot/state"] * 2


def _listening_addresses(port: int) -> set[str]:
    """Local addresses with a socket in LISTEN state on ``port`` (from /proc/net/tcp and tcp6)."""
    found = set()
    for name in ("tcp", "tcp6"):
        path = f"/proc/net/{name}"
        if not os.path.exists(path):
            continue
        for line in open(path).read().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            addr, p = local.split(":")
            if int(p, 16) == port and state == "0A":
                found.add(addr)
    return found


@pytest.mark.skipif(not os.path.exists("/proc/net/tcp"), reason="needs Linux /proc/net/tcp")
def test_the_server_listens_on_loopback_only_and_a_taken_port_is_a_clear_error():
    with LiveView(port=0) as view:
        assert view.host == "127.0.0.1" and view.url == f"ws://127.0.0.1:{view.port}"
        assert _listening_addresses(view.port) == {"0100007F"}       # 127.0.0.1, nothing else
        with pytest.raises(ViewError, match=rf"cannot serve the live view on 127\.0\.0\.1:{view.port}: .*in use"):
            LiveView(port=view.port)
    with pytest.raises(ViewError, match="port must be an integer 0-65535"):
        LiveView(port=70000)


@pytest.mark.parametrize("args,code", [(["--help"], 0), (["--out", "x.json"], 2)])
def test_the_layout_writer_given_any_argument_says_what_it_does_and_writes_nothing(args, code):
    """`python -m flagbot_sim.view.layout --help` rewrote the shipped file (it read no arguments)."""
    before = live.LAYOUT_FILE.stat().st_mtime_ns
    p = subprocess.run([sys.executable, "-m", "flagbot_sim.view.layout", *args], cwd=ROOT, capture_output=True,
                       text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert p.returncode == code and "usage: python -m flagbot_sim.view.layout" in p.stderr
    assert live.LAYOUT_FILE.stat().st_mtime_ns == before


def test_the_shipped_layout_is_current_and_shows_only_what_the_view_publishes():
    shipped = live.LAYOUT_FILE.read_text()
    assert shipped == layout.text(), "run: python -m flagbot_sim.view.layout"
    lay = json.loads(shipped)
    panels = lay["configById"]
    three_d = [v for k, v in panels.items() if k.startswith("3D!")]
    assert len(three_d) == 1 and set(three_d[0]["topics"]) <= set(TOPICS)
    assert three_d[0]["followTf"] == "head" and three_d[0]["fixedFrame"] == "world"
    from flagbot_sim.view.scene_msgs import STATE_SCHEMA
    plotted = [p["value"] for k, v in panels.items() if k.startswith("Plot!") for p in v["paths"]]
    assert {"omega_T", "omega_h", "omega_t", "v", "motor_torque"} <= {p.split(".", 1)[1] for p in plotted}
    for p in plotted:
        topic, field = p.split(".", 1)
        assert topic == "/flagbot/state" and field in STATE_SCHEMA["properties"], p

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])
    assert sorted(leaves(lay["layout"])) == sorted(panels), "every panel is placed exactly once"


def test_flagbot_run_view_serves_the_run_to_a_client(tmp_path):
    """The user's path: ``flagbot run --view`` as a process; a client connects while it waits, and sees it run."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "flagbot_sim", "run", "design2", "--duration", "0.3", "--json",
                             "--view", "--view-port", "0", "--view-wait", "20", "--view-rtf", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    try:
        line = proc.stderr.readline()
        m = re.search(r"live view: (ws://127\.0\.0\.1:\d+) ", line)
        assert m, line

        async def watch():
            c = await Client.connect(m.group(1))
            await c.subscribe({"/flagbot/state", "/flagbot/scene"})
            states = []
            try:
                while True:
                    topic, _, msg = await c.receive(timeout=20)
                    if topic == "/flagbot/state":
                        states.append(msg)
            except Exception:        # the run ended: the server closed the connection
                pass
            return states
        states = run(watch())
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    summary = json.loads(out)
    ts = [s["t"] for s in states]
    # paced at real time and capped at 30 Hz: from the start (t = 0) to the final state, several in between
    assert ts[0] == 0.0 and ts[-1] == pytest.approx(summary["time"]) and ts == sorted(ts) and len(ts) >= 4
    assert all(np.isfinite(list(s.values())).all() for s in states)
    # the pacing is reported apart from the stepping's own speed: 0.3 s simulated took at least 0.3 s of wall
    assert summary["paced_wall_seconds"] >= 0.3 and summary["paced_real_time_factor"] <= 1.0 + 1e-6
    assert summary["wall_seconds"] < summary["paced_wall_seconds"]


def test_without_the_extra_flagbot_run_view_says_so_in_one_line(tmp_path):
    p = subprocess.run([sys.executable, "-c", "import sys; sys.modules['foxglove'] = None; from flagbot_sim.cli "
                        "import main; sys.exit(main(['run', 'design2', '--duration', '0.01', '--view']))"],
                       capture_output=True, text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                       cwd=tmp_path)
    assert p.returncode == 2 and p.stdout == ""           # optional.EXIT_CODE: the same for every missing extra
    assert p.stderr.count("\n") == 1, p.stderr
    assert "the Foxglove live view needs the Foxglove SDK" in p.stderr
    assert p.stderr.rstrip().endswith("pip install 'flagbot_sim[view]'")
