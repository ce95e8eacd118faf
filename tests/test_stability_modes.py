"""The stability report separates the flagella's almost undamped twist oscillations from the relaxation of the
shape, and the shape's settling rate is what a time-stepped run shows."""
import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.steady import TWIST_SHARE, SteadySolver, summary
from flagbot_sim.scene import load_scene

D2_CLAMPED = ["flagellum.length=0.089", "medium.mu=2.125", "plate.diameter=0.03"]


@pytest.mark.parametrize("over,t0,t1", [(["motor.omega_rpm=0.5"], 3.0, 9.0), (["motor.omega_rpm=20"], 3.0, 9.0),
                                        (D2_CLAMPED + ["motor.omega_rpm=1"], 0.5, 2.0)])
def test_the_clamped_flagellums_settling_rate_is_its_time_stepped_one(over, t0, t1):
    """From rest, the tip (in the frame turning with the clamp) approaches its steady position as
    exp(shape_rate t): the slope of log|tip - tip_steady| over the run's later part is the stability report's
    shape rate to 1%, while its slowest mode overall is an almost undamped twist oscillation at ~300 rad/s that
    the centreline does not show (its slowest time constant is 10-1000x longer)."""
    sc = load_scene("clamped_flagellum", over)
    m = RobotModel(sc)
    S = SteadySolver(m)
    sol = S.solve(sc.omega_T)
    st = S.stability(sol)
    d = st.to_dict()
    assert st.stable and st.twist_frequency > 250.0 and st.twist_rate > st.shape_rate
    assert d["slowest_time_constant"] > 10 * d["settling_time_constant"]
    assert d["settling_time_constant"] == pytest.approx(-1.0 / st.shape_rate)
    assert d["twist_oscillation"]["frequency"] == st.twist_frequency
    # the kinds are clear-cut: a mode's twist share is ~1 or ~0
    shares = np.array(st.twist_shares)
    assert np.all((shares > 0.99) | (shares < 0.01)) and (shares > TWIST_SHARE).any()
    tip = np.array(summary(m, sol)["tip"])
    sim = Simulation(sc)
    ts, ds = [], []
    while sim.time < t1:
        sim.step()
        if sim.time >= t0:
            ts.append(sim.time)
            ds.append(np.linalg.norm(sim.clamp_frame_tip() - tip))
    slope = np.polyfit(ts, np.log(ds), 1)[0]
    assert slope == pytest.approx(st.shape_rate, rel=0.01)


def test_with_spin_drag_the_twist_is_damped_and_the_free_robot_reports_its_shape_rate():
    """The free robot has no separate twist oscillation among its slowest modes (its settling time is its
    slowest one); with the spin drag listed, the clamped flagellum's twist modes are damped."""
    sc = load_scene("design2")
    S = SteadySolver(RobotModel(sc))
    st = S.stability(S.solve(sc.omega_T))
    assert st.neutral == 4 and st.shape_rate == st.rate < 0
    out = {}
    for effects in ("['inertia','rft','clamp']", "['inertia','rft','clamp','spin_drag']"):
        sc = load_scene("clamped_flagellum", ["motor.omega_rpm=0.5", f"scene.effects={effects}",
                                              "medium.spin_drag=viscous"])
        S = SteadySolver(RobotModel(sc))
        out[effects] = S.stability(S.solve(sc.omega_T))
    plain, spin = out.values()
    assert plain.twist_rate > -1e-3                       # almost undamped without it
    assert not np.isfinite(spin.twist_rate) or spin.twist_rate < -1.0
    assert spin.shape_rate == pytest.approx(plain.shape_rate, rel=0.05)
