"""Test-wide environment: DDS stays on this machine, each test process gets its own ROS domain and log dir.

ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, then the package's own loopback-only DDS profile on top of it
(flagbot_sim/ros/dds.py), exactly as every flagbot process applies it: this process's probe nodes and every node
the tests start (they inherit this environment) bind DDS to 127.0.0.1 only.
"""
import os
import tempfile

from flagbot_sim.ros.dds import configure_dds, loopback_only

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("FLAGBOT_DDS_NETWORK", None)     # no test widens discovery: an opt-in from the shell is dropped
for _var in ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE"):
    os.environ.pop(_var, None)                  # nor does a profile of the user's: the tests run on ours
configure_dds(os.environ)
assert loopback_only(os.environ)
# one domain per test process (0-232 are valid); pytest-xdist workers are separate processes
os.environ.setdefault("ROS_DOMAIN_ID", str(20 + os.getpid() % 200))
if "ROS_LOG_DIR" not in os.environ:        # dev.py sets it; setdefault would still create an empty dir
    os.environ["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="flagbot_roslog_")
os.environ.setdefault("MPLBACKEND", "Agg")


import pytest  # noqa: E402
from hypothesis import settings as _hypothesis  # noqa: E402

# The suite's verdict is reproducible: its property tests draw the same examples on every run and machine
# (FLAGBOT_FUZZ unset). `python3 dev.py fuzz [N]` explores instead: fresh random examples, N per property test.
_hypothesis.register_profile("gate", derandomize=True)
_hypothesis.register_profile("explore", derandomize=False)
_hypothesis.load_profile("explore" if os.environ.get("FLAGBOT_FUZZ") else "gate")
#: examples per property test: the gate's fixed 300, or what `dev.py fuzz N` asks for
FUZZ_EXAMPLES = int(os.environ.get("FLAGBOT_FUZZ") or 300)

# design 2's flagellum (L = 89 mm, mu = 2.125 Pa s, R_d = 1.5 cm) on the clamped_flagellum scene
DESIGN2_CLAMPED = ["flagellum.length=0.089", "medium.mu=2.125", "plate.diameter=0.03"]


@pytest.fixture(scope="module")
def ros(request):
    """An rclpy context and a probe node for one test module (each module talks to the nodes it starts)."""
    import rclpy
    from rclpy.node import Node
    rclpy.init()
    node = Node(request.module.__name__.replace(".", "_") + "_probe")
    yield node
    node.destroy_node()
    rclpy.shutdown()


@pytest.fixture(scope="session")
def clamped_design2():
    """``run(rpm) -> (scene, summary)``: design 2's clamped flagellum at ``rpm``, run to the steady-state rule
    (at most 20 s of simulated time).

    Each rpm is simulated once per session; the scene and summary are shared, so callers must not mutate them.
    """
    from flagbot_sim.physics import Simulation
    from flagbot_sim.scene import load_scene
    cache = {}

    def run(rpm):
        rpm = float(rpm)
        if rpm not in cache:
            sc = load_scene("clamped_flagellum", [*DESIGN2_CLAMPED, f"motor.omega_rpm={rpm}"])
            sim = Simulation(sc)
            sim.run_until_steady(20.0)
            cache[rpm] = (sc, sim.summary())
        return cache[rpm]
    return run
