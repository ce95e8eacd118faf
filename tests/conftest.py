"""Test-wide environment: DDS stays on this machine, each test process gets its own ROS domain and log dir."""
import os
import tempfile

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# one domain per test process (0-232 are valid); pytest-xdist workers are separate processes
os.environ.setdefault("ROS_DOMAIN_ID", str(20 + os.getpid() % 200))
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="flagbot_roslog_"))
os.environ.setdefault("MPLBACKEND", "Agg")


import pytest  # noqa: E402


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
