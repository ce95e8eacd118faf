"""`flagbot demo` runs in the ROS domain the user exported (or the one given with --domain), else one of its own.

The full demo (three nodes, a minute of simulated time) is the main job (`python3 dev.py run`); here only the
choice of domain, through the function and through the real command line."""
import math

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


def test_the_step_table_takes_the_beam_prediction_whose_split_is_the_steps_command():
    """beam_node re-publishes its last prediction while it solves for the next command, so a value tagged with
    the new command can be the old prediction (before: a 0.0000 row for every step of a short demo); the one
    for a step is the one whose omega_h + omega_t equals the step's omega_T, whenever it arrived."""
    from flagbot_sim.ros.demo import step_table
    samples = {k: [(t, 1.0) for t in (1.0, 1.9, 3.0, 3.9)] for k in ("omega_h", "omega_t", "v")}
    beam = [(0.5, 5.0, (0.0, 0.0, 0.0)),            # stale: the prediction for omega_T = 0, tagged with 5
            (2.5, 10.0, (4.8, 0.2, 1e-4)),          # the 5 rad/s prediction, arriving during the next step
            (3.5, 10.0, (9.5, 0.5, 2e-4))]
    rows = step_table(samples, [(0.0, 2.0, 5.0), (2.0, 4.0, 10.0), (4.0, 6.0, 20.0)], beam)
    assert [(r["beam_omega_h"], r["beam_v"]) for r in rows[:2]] == [(4.8, 1e-4), (9.5, 2e-4)]
    assert math.isnan(rows[2]["beam_omega_h"]) and math.isnan(rows[2]["omega_h"])
