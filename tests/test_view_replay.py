"""``flagbot replay --view``: a recording played into the live view, and its frames (tests/foxglove_client.py).

A client subscribed to the view receives scenes whose flagellum points are the recorded markers' points at the
stamp the message carries. A recording without markers is re-simulated from its command stream: the shape is then
the simulated one, and the head moves exactly where the recorded head_pose says (within the re-simulation's
tolerance).
"""
import asyncio
import threading

import numpy as np
import pytest
from cli_helpers import ROOT
from foxglove_client import Client

from flagbot_sim import cli
from flagbot_sim.bag import BagReader, BagWriter
from flagbot_sim.runs.resim import POSITION_TOLERANCE
from flagbot_sim.view import recorded
from flagbot_sim.view.live import LiveView
from flagbot_sim.view.replay import play

SAMPLE = ROOT / "bags" / "design2_n2_steps.mcap"


def _stamp(m) -> float:
    return round(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, 9)


def test_a_client_sees_the_recorded_markers_played_back():
    run = recorded.load(SAMPLE)
    assert run.source == "markers" and len(run.frames) > 100
    with BagReader(SAMPLE) as r:
        markers = {_stamp(m.markers[0]): m for _, _, m in r.decoded("/markers")}
    with LiveView(port=0, max_rate=20.0) as view:
        async def scenario():
            c = await Client.connect(view.url)
            await c.subscribe({"/flagbot/scene", "/flagbot/state"})
            while not view.has_clients():
                await asyncio.sleep(0.01)
            done = threading.Event()
            shown = []
            th = threading.Thread(target=lambda: (shown.append(play(run, view, rate=40.0, start_offset=8.0)),
                                                  done.set()))
            th.start()
            got = []
            while not (done.is_set() and len(got) >= 2 * shown[0]):
                got.append(await c.receive(timeout=10))
            th.join()
            await c.close()
            return got, shown[0]
        got, shown = asyncio.run(asyncio.wait_for(scenario(), 60))
    scenes = [(lt, msg) for topic, lt, msg in got if topic == "/flagbot/scene"]
    states = {lt: msg for topic, lt, msg in got if topic == "/flagbot/state"}
    # ~8 s of recording at 40x: ~0.2 s of wall time at <= 20 per second, first and last frame always shown
    assert 3 <= shown <= 10 and len(scenes) == shown
    assert scenes[-1][0] == round(run.frames[-1].t * 1e9)
    for lt, msg in scenes:
        rec = markers[round(lt * 1e-9, 9)]
        flag = {mk.id: mk for mk in rec.markers if mk.ns == "flagella"}
        ents = {e["id"]: e for e in msg["entities"]}
        for i, mk in flag.items():
            drawn = [[p["x"], p["y"], p["z"]] for p in ents[f"flagellum/{i}"]["lines"][0]["points"]]
            assert drawn == [[p.x, p.y, p.z] for p in mk.points]
        assert ents["flagellum/0"]["lines"][0]["thickness"] == pytest.approx(2 * 3.2e-3)
        assert states[lt]["t"] == pytest.approx(lt * 1e-9) and np.isfinite(states[lt]["omega_h"])


def test_a_recording_without_markers_is_resimulated(tmp_path):
    # the sample recording's first 2 s without its markers
    out = tmp_path / "nomarkers.mcap"
    with BagReader(SAMPLE) as r:
        meta = r.run_metadata()
        start = r.report.start_ns
        keep = {t: i.type_name for t, i in r.topics.items() if t in ("/joint_states", "/head_pose", "/clock")}
        with BagWriter(out, metadata=meta) as w:
            for t, ty in keep.items():
                w.add_topic(t, ty)
            for m in r.messages(list(keep)):
                if m.log_time_ns - start > 4.5e9:
                    break
                w.write(m.topic, m.data, m.log_time_ns, m.publish_time_ns)
    with BagReader(out) as r:
        poses = {_stamp(m): m.pose.position for _, _, m in r.decoded("/head_pose")}
    run = recorded.load(out)
    assert run.source == "resimulated" and any("re-simulated" in n for n in run.notes)
    assert len(run.frames) > 50 and run.frames[-1].t > 1.0
    err = max(np.linalg.norm(f.head_centre - [poses[round(f.t, 9)].x, poses[round(f.t, 9)].y,
                                              poses[round(f.t, 9)].z]) for f in run.frames if round(f.t, 9) in poses)
    assert err <= POSITION_TOLERANCE
    assert len(run.frames[0].flagella) == 2


def test_flagbot_replay_view_refuses_a_file_that_is_no_recording(tmp_path, capsys):
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"not an mcap file")
    assert cli.main(["replay", str(bad), "--view", "--view-port", "0"]) == 2
    assert capsys.readouterr().err.startswith("error: ")
