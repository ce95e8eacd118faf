"""The ``replay`` console script takes the arguments of ``flagbot replay`` and honours them the same way."""
import json
import os
import subprocess
import sys

import pytest
from cli_helpers import ROOT, flagbot

BAG = ROOT / "bags" / "design2_n2_steps.mcap"      # the shortest sample recording


def replay_script(*args, timeout=120):
    """The ``replay`` console script (setup.py: ``flagbot_sim.ros.replay:main``, also scripts/replay) run as
    ``python -m flagbot_sim.ros.replay ARGS``; the CompletedProcess."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "flagbot_sim.ros.replay", *args], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=timeout)


@pytest.mark.parametrize("extra", [["--json"], []], ids=["json", "text"])
def test_replay_script_resimulates_like_flagbot_replay(extra):
    assert BAG.is_file()
    got = replay_script(str(BAG), "--resimulate", *extra)
    want = flagbot("replay", str(BAG), "--resimulate", *extra)
    assert want.returncode == 0, want.stderr
    assert got.returncode == 0, got.stderr
    assert got.stdout == want.stdout
    if extra:   # a re-simulation report, not a ROS replay's statistics
        res = json.loads(got.stdout)
        assert res["bag"] == str(BAG) and res["samples"] > 10 and len(res["commands"]) >= 2
    else:
        assert got.stdout.startswith(f"re-simulation of {BAG}: ")
