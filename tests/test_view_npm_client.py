"""The live view as Lichtblick and older Foxglove Studio meet it: the unmodified npm client ``@foxglove/ws-protocol``
(``FoxgloveClient``, 0.8.0) under Node, offering only the subprotocol ``foxglove.websocket.v1``.

The packages (ws-protocol, the ``ws`` WebSocket for Node, protobufjs to decode with the schema the server
advertises) are installed from the npm registry on first use into a cache outside the repository
(tests/npm_helpers.py). The client connects, reads serverInfo and the channels, subscribes to the scene and the
state, and decodes them in JavaScript; here the decoded flagellum points are compared with the simulation's nodes.
"""
import json

import numpy as np
import pytest
from npm_helpers import node_modules, run_node
from view_testlib import Publishing, stepped_design2

from flagbot_sim import world
from flagbot_sim.view.bridge import LEGACY_SUBPROTOCOL
from flagbot_sim.view.live import TOPICS, LiveView


@pytest.fixture(scope="module")
def npm():
    return node_modules()


@pytest.fixture(scope="module")
def sim():
    return stepped_design2(3)


def xyz(p) -> list:
    return [p["x"], p["y"], p["z"]]


def test_the_npm_foxglove_client_offering_only_the_old_name_connects_and_decodes_the_simulated_robot(npm, sim):
    snap = sim.snapshot()
    refused = []
    with LiveView(port=0, log=refused.append) as view, Publishing(view, sim):
        p = run_node("foxglove_ws_client.js", view.url, "/flagbot/scene", "/flagbot/state", "/tf")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    # it offered only the old name, and the handshake chose it
    assert out["offered"] == [LEGACY_SUBPROTOCOL] and out["subprotocol"] == LEGACY_SUBPROTOCOL
    assert refused == []
    info = out["serverInfo"]
    assert info["op"] == "serverInfo" and info["name"] == "flagbot_sim" and "time" in info["capabilities"]
    channels = {c["topic"]: c for c in out["channels"]}
    assert set(channels) == set(TOPICS)
    assert channels["/flagbot/scene"]["schemaName"] == "foxglove.SceneUpdate"
    assert channels["/flagbot/scene"]["encoding"] == "protobuf"
    assert channels["/flagbot/state"]["encoding"] == "json"

    msgs = out["messages"]
    t_ns = int(round(sim.time * 1e9))
    assert {m["logTime"] for m in msgs.values()} == {str(t_ns)}, "log time = simulated time"
    # the scene, decoded by protobufjs from the advertised FileDescriptorSet: one line per flagellum through the
    # simulation's nodes in the world frame, to the last bit (doubles survive protobuf, JavaScript and JSON)
    entities = {e["id"]: e for e in msgs["/flagbot/scene"]["message"]["entities"]}
    assert set(entities) == {"head", "plate", "flagellum/0", "flagellum/1", "flagellum/2"}
    centrelines = sim.flagella_centrelines()
    assert len(centrelines) == 3
    for i, nodes in enumerate(centrelines):
        line = entities[f"flagellum/{i}"]["lines"][0]
        np.testing.assert_array_equal([xyz(q) for q in line["points"]], world.to_world(nodes, sim.observer.origin))
        assert line["thickness"] == 2 * sim.scene.flagellum.radius
        assert entities[f"flagellum/{i}"]["frameId"] == "world"
    head = entities["head"]["spheres"][0]
    np.testing.assert_allclose(xyz(head["pose"]["position"]), snap.position, rtol=0, atol=1e-15)
    # world -> head and the plotted numbers
    tf = msgs["/tf"]["message"]["transforms"][0]
    assert (tf["parentFrameId"], tf["childFrameId"]) == ("world", "head")
    np.testing.assert_allclose(xyz(tf["translation"]), snap.position, rtol=0, atol=1e-15)
    state = msgs["/flagbot/state"]["message"]
    for k in ("omega_h", "omega_t", "omega_T", "v", "motor_torque", "t"):
        assert state[k] == getattr(snap, k), k
    assert snap.omega_h != 0 and snap.motor_torque != 0


def test_the_sdk_alone_refuses_that_client_which_is_why_the_bridge_exists(npm):
    """Straight to the SDK's own port the same client is refused (HTTP 400): if a future SDK accepts the old
    name, this fails, and the bridge can go."""
    with LiveView(port=0) as view:
        p = run_node("foxglove_ws_client.js", f"ws://127.0.0.1:{view.bridge.backend_port}", "/flagbot/state")
    assert p.returncode == 1
    assert "400" in p.stderr, p.stderr
