"""The ``replay`` console script takes the arguments of ``flagbot replay`` and honours them the same way, and
``--resimulate`` ends with a verdict: exit 0 when the recording is reproduced, 1 when it is not."""
import json
import os
import subprocess
import sys

import pytest
from cli_helpers import ROOT, flagbot

BAG = ROOT / "bags" / "design2_n2_steps.mcap"      # the shortest sample recording


def replay_script(*args, timeout=120):
    """The ``replay`` console script (setup.py: ``flagbot_sim.console:replay``, also scripts/replay) run as
    ``python -m flagbot_sim.commands.replay ARGS``; the CompletedProcess."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "flagbot_sim.commands.replay", *args], capture_output=True,
                          text=True, env=env, cwd=ROOT, timeout=timeout)


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
        assert res["reproduced"] is True and res["verdict"].startswith("verdict: REPRODUCED")
    else:
        assert got.stdout.startswith(f"re-simulation of {BAG}: ")
        assert got.stdout.strip().splitlines()[-1].startswith("verdict: REPRODUCED: ")


def tampered_copy(src, dst, *, seconds=3.0, scene_edit=("mu = 2.125", "mu = 2.14625")):
    """A recording's motion (joint_states, head_pose) up to `seconds` after its first command, with its stored
    scene edited: the same commands now drive a robot in a 1 % more viscous medium, so the re-simulation must not
    match."""
    from flagbot_sim.bag import BagReader, BagWriter, RunMetadata, qos_to_yaml
    with BagReader(src) as r:
        meta = r.run_metadata()
        assert scene_edit[0] in meta.scene_toml
        meta = RunMetadata(**{**meta.__dict__, "scene_toml": meta.scene_toml.replace(*scene_edit)})
        keep = ["/joint_states", "/head_pose"]
        with BagWriter(dst, metadata=meta) as w:
            for t in keep:
                info = r.topics[t]
                w.add_topic(t, info.type_name, offered_qos_profiles=qos_to_yaml(info.offered_qos))
            # the device idles until its first command (the demo's nodes start and discover each other first)
            start = next(m.log_time_ns for m in r.messages(["/cmd_omega"]))
            end = start + int(seconds * 1e9)
            for m in r.messages(keep):
                if m.log_time_ns <= end:
                    w.write(m.topic, m.data, m.log_time_ns, m.publish_time_ns)


def test_resimulate_says_when_the_recording_is_not_reproduced_and_exits_1(tmp_path):
    bad = tmp_path / "viscous.mcap"
    tampered_copy(BAG, bad)
    r = flagbot("replay", str(bad), "--resimulate", "--json")
    assert r.returncode == 1, r.stdout + r.stderr
    res = json.loads(r.stdout)
    assert res["reproduced"] is False and res["verdict"].startswith("verdict: DIFFERS")
    assert res["max_omega_h_error"] > 10 * res["tolerance"]["rate_rad_s"]
    print("1 % more viscosity:", res["verdict"])
    r = replay_script(str(bad), "--resimulate")
    assert r.returncode == 1, r.stdout + r.stderr
    last = r.stdout.strip().splitlines()[-1]
    assert last.startswith("verdict: DIFFERS: ") and "omega_h by" in last and "beyond the tolerance" in last


@pytest.mark.parametrize("flag,value", [("--delay", "-5"), ("--delay", "nan"), ("--wait-for-subscribers", "-1"),
                                        ("--wait-for-subscribers", "inf")])
def test_replay_refuses_a_negative_or_non_finite_wait_before_starting_ros(flag, value):
    """A wait of -5 s, nan or inf was accepted (inf waited for subscribers for ever); now one error line naming
    the flag, exit 2, and no ROS node ever started (the refusal comes before rclpy is imported)."""
    p = flagbot("replay", str(BAG), flag, value)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines() == [f"error: {flag} must be a finite number of seconds >= 0, got "
                                             f"{float(value)}"]
