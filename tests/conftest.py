"""Test-wide environment: DDS stays on this machine, each test process gets its own ROS domain and log dir."""
import os
import tempfile

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
# one domain per test process (0-232 are valid); pytest-xdist workers are separate processes
os.environ.setdefault("ROS_DOMAIN_ID", str(20 + os.getpid() % 200))
os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="flagbot_roslog_"))
os.environ.setdefault("MPLBACKEND", "Agg")
