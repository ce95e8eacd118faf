"""sim_node serves the live view to a Foxglove client when asked (foxglove_port), on loopback, and refuses a port
it cannot serve without changing anything."""
import asyncio
import socket

import numpy as np
import pytest
from rosgraph_msgs.msg import Clock

from ros_helpers import DISCOVERY_TIMEOUT, EVENT_TIMEOUT, NodeProcess, set_params, spin_until

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")
from foxglove_client import Client  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_sim_node_serves_the_robot_to_a_foxglove_client(ros):
    port = free_port()
    proc = NodeProcess("flagbot_sim.ros.sim_node", "--ros-args", "-p", "scene:=design2", "-p", "n_flagella:=3",
                       "-p", "initial_omega:=5.0", "-p", f"foxglove_port:={port}")
    clock = []
    sub = ros.create_subscription(Clock, "/clock", clock.append, 10)
    try:
        # the node is serving once it publishes (its view opens before its timer starts)
        spin_until(ros, lambda: clock, DISCOVERY_TIMEOUT, "/clock from sim_node")

        async def watch():
            # the protocol's first name (Lichtblick, @foxglove/ws-protocol) is served like the SDK's
            c = await Client.connect(f"ws://127.0.0.1:{port}", timeout=EVENT_TIMEOUT,
                                   subprotocol="foxglove.websocket.v1")
            await c.subscribe({"/flagbot/state", "/flagbot/scene"})
            got = await c.collect({"/flagbot/state", "/flagbot/scene"}, timeout=EVENT_TIMEOUT)
            await c.close()
            # a client offering neither is refused (HTTP 400), and the node's log says what it offered
            with pytest.raises(websockets.InvalidStatus, match="400"):
                await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.ros.v9"])
            return got
        got = asyncio.run(watch())
        state = got["/flagbot/state"][-1][1]
        assert state["omega_T"] == pytest.approx(5.0) and np.isfinite(state["v"])
        scene = got["/flagbot/scene"][-1][1]
        strips = [e for ent in scene["entities"] for e in ent.get("lines", [])]
        assert len(strips) >= 3          # one per flagellum
        # a port in use cannot be served: refused with the reason, the view goes on where it was
        busy = socket.socket()
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        (res,) = set_params(ros, "sim_node", foxglove_port=busy.getsockname()[1])
        busy.close()
        assert not res.successful and "in use" in res.reason, res.reason
    finally:
        ros.destroy_subscription(sub)
        code, out = proc.stop()
    assert code == 0, out
    assert "live view: refused a client from 127.0.0.1:" in out and \
        "it offered the WebSocket subprotocols 'foxglove.ros.v9'" in out, out
