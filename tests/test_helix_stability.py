"""A soft helical flagellum clamped in a turning plate in a viscous fluid loses its steady state at a critical
rotation rate (docs/helical_viscous.md): the steady solver's branch ends in a fold, where its slowest decay rate
goes to zero, and the time-stepped flagellum settles on the branch below the fold but not above it."""
import math

import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.steady import SteadyFailed, SteadySolver, summary
from flagbot_sim.scene import load_scene
from flagbot_sim.units import RPM

SOFT_HELIX = ["flagellum.helix_pitch=-0.05", "medium.model=viscous", "medium.mu=1.2", "flagellum.youngs_modulus=5e4"]


@pytest.fixture(scope="module")
def branch():
    sc = load_scene("clamped_flagellum", SOFT_HELIX)
    m = RobotModel(sc)
    S = SteadySolver(m)
    out, prev = {}, None
    for rpm in (50, 100, 150, 200, 250, 270, 280, 282):          # continued along the stable branch
        prev = S.solve(rpm * RPM, start=prev)
        out[rpm] = (summary(m, prev), S.stability(prev))
    return S, prev, out


def test_the_steady_branch_ends_in_a_fold_where_the_slowest_decay_vanishes(branch):
    S, last, out = branch
    assert all(st.stable for _, st in out.values())
    # approaching the fold the slowest mode is real and its decay rate tends to zero
    rates = [out[r][1].rate for r in (270, 280, 282)]
    assert rates[0] < rates[1] < rates[2] < 0 and rates[2] > 0.3 * rates[0]
    assert abs(out[282][1].rates[0].imag) < 1e-9
    with pytest.raises(SteadyFailed, match="no relative equilibrium"):
        S.solve(290 * RPM, start=last)


def run_clamped(rpm, seconds):
    sim = Simulation(load_scene("clamped_flagellum", SOFT_HELIX + [f"motor.omega_rpm={rpm}"]))
    fx = []
    while sim.time < seconds - 1e-9:
        sim.run(1.0)
        fx.append(sim.medium_force_on_flagella()[0][0])
    return sim, np.array(fx)


def test_time_stepping_settles_on_the_branch_below_the_fold_and_not_above(branch):
    _, _, out = branch
    sim, fx = run_clamped(250, 30.0)
    assert sim.steady
    # (time.dt = 1e-2 s turns the clamp 0.26 rad per step: BDF2's own error is ~0.3% of the force here)
    assert fx[-1] == pytest.approx(out[250][0]["Fx"], rel=5e-3)
    # above the fold: no steady state to settle on; the flagellum keeps deforming (the axial force swings)
    sim, fx = run_clamped(300, 30.0)
    assert not sim.steady
    late = fx[10:]
    assert late.max() - late.min() > 0.3 * abs(out[282][0]["Fx"])
