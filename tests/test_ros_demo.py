"""`flagbot demo` runs in the ROS domain the user exported (or the one given with --domain), else one of its own.

The full demo (three nodes, a minute of simulated time) is the main job (`python3 dev.py run`); here only the
choice of domain, through the function and through the real command line."""
import pytest

from flagbot_sim.ros.demo import demo_domain

from cli_helpers import flagbot


def test_domain_comes_from_the_option_then_the_environment_then_the_pid():
    assert demo_domain(7, {"ROS_DOMAIN_ID": "42"}, pid=12345) == 7
    assert demo_domain(None, {"ROS_DOMAIN_ID": "42"}, pid=12345) == 42
    assert demo_domain(None, {"ROS_DOMAIN_ID": " 0 "}, pid=12345) == 0
    assert demo_domain(None, {}, pid=12345) == 145
    assert demo_domain(None, {"ROS_DOMAIN_ID": ""}, pid=12345) == 145      # exported but empty: unset
    for bad in ("abc", "233", "-1", "1.5"):
        with pytest.raises(ValueError, match="ROS_DOMAIN_ID"):
            demo_domain(None, {"ROS_DOMAIN_ID": bad}, pid=1)
    with pytest.raises(ValueError, match="--domain"):
        demo_domain(300, {}, pid=1)


def test_the_command_reads_the_exported_domain(monkeypatch):
    # an exported id the demo would use is checked before any node starts: a bad one is a one-line refusal
    monkeypatch.setenv("ROS_DOMAIN_ID", "999")
    r = flagbot("demo", "--step-duration", "0.1", timeout=120)
    assert r.returncode == 2, r.stdout + r.stderr
    assert r.stderr.strip() == "error: ROS_DOMAIN_ID = 999 is out of range: a ROS domain id is 0-232"
