"""The free robot at omega_T = 100 rpm with the paper's parameters, discretisation and fitted constants.

These runs use the paper's dt = 1e-2 s and 4.11 mm edges and go to a detected steady state (about 20 s of
simulated time for design 1, whose flagella relax slowly: eta_p L^4 / EI = 28 s).
"""
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.scene import load_scene


def steady(scene, n, duration=20.0):
    sim = Simulation(load_scene(scene, [f"robot.n_flagella={n}", "motor.omega_rpm=100"]))
    sim.run(duration)
    out = sim.summary()
    assert out["steady"], f"{scene} n={n} not steady after {duration} s: {out}"
    return out


@pytest.fixture(scope="module")
def runs():
    return {(s, n): steady(s, n) for s in ("design1", "design2") for n in (2, 3)}


@pytest.mark.parametrize("key", [("design1", 2), ("design1", 3), ("design2", 2), ("design2", 3)])
def test_motor_speed_splits_into_head_and_flagella_counter_rotation(runs, key):
    out = runs[key]
    # paper Eq. totalOmega: omega_T = omega_h + omega_t; head and flagella turn in opposite directions
    assert out["omega_h"] + out["omega_t"] == pytest.approx(out["omega_T"], rel=0.01)
    assert out["omega_h"] > 0 and out["omega_t"] > 0
    # the robot swims head first (forward = towards the head, -x)
    assert out["v"] > 0


def test_head_takes_most_of_the_motor_speed_in_design1_and_about_half_in_design2(runs):
    for n in (2, 3):
        assert runs[("design1", n)]["omega_h"] / runs[("design1", n)]["omega_T"] > 0.8
        assert 0.35 < runs[("design2", n)]["omega_h"] / runs[("design2", n)]["omega_T"] < 0.7


def test_design1_two_flagella_are_faster_than_three(runs):
    assert runs[("design1", 2)]["v"] > runs[("design1", 3)]["v"]


def test_design2_three_flagella_are_at_least_as_fast_as_two(runs):
    assert runs[("design2", 3)]["v"] >= runs[("design2", 2)]["v"]


def test_reversed_motor_mirrors_the_motion():
    """Turning the motor the other way reverses both spins but, by symmetry, not the direction of travel."""
    fwd = Simulation(load_scene("design2", ["flagellum.length=0.05", "motor.omega_rpm=100"]))
    rev = Simulation(load_scene("design2", ["flagellum.length=0.05", "motor.omega_rpm=-100"]))
    fwd.run(3.0)
    rev.run(3.0)
    a, b = fwd.summary(), rev.summary()
    assert b["omega_h"] == pytest.approx(-a["omega_h"], rel=1e-6)
    assert b["omega_t"] == pytest.approx(-a["omega_t"], rel=1e-6)
    assert b["v"] == pytest.approx(a["v"], rel=1e-5) and a["v"] > 0
