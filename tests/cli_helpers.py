"""The repository root and the `flagbot` command run as users run it: a separate process (no rclpy here)."""
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def flagbot(*args, check=False, timeout=600):
    """``python -m flagbot_sim ARGS`` from the checkout; the CompletedProcess, with text stdout and stderr."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "flagbot_sim", *args], capture_output=True, text=True,
                          env=env, cwd=ROOT, check=check, timeout=timeout)
