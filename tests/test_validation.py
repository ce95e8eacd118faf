"""The DER flagellum against closed-form beam theory."""
import math

import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.medium import bending_stiffness, normalise_omega, rft_coefficients
from flagbot_sim.scene import load_scene


def cantilever_tip_error(edge_length):
    """Static tip deflection of the clamped flagellum under a uniform transverse load, relative to p L^4 / 8 EI.

    The load is the 'gravity' effect on the flagellum's Voronoi-lumped masses (uniform p = rho A g); with no
    inertia and no drag, one implicit step is a static solve.
    """
    base = load_scene("clamped_flagellum", ["scene.effects=['gravity','clamp']", "motor.omega_rpm=0",
                                            f"flagellum.edge_length={edge_length}"])
    L, EI = base.flagellum.length, bending_stiffness(base)
    p = 8e-4 * EI / L ** 3                            # w(L)/L = 1e-4: the linear regime
    g = p / (base.flagellum.density * math.pi * base.flagellum.radius ** 2)
    sim = Simulation(base.with_overrides({"gravity.g": [0.0, 0.0, -g]}))
    sim.step(1.0)
    w_tip = -sim.flagella_centrelines()[0][-1][2]
    return w_tip / (p * L ** 4 / (8 * EI)) - 1.0


def test_cantilever_matches_euler_bernoulli_and_converges():
    errors = [abs(cantilever_tip_error(h)) for h in (8.22e-3, 4.11e-3, 2.055e-3)]
    assert errors[1] < 0.01                           # the paper's 4.11 mm edges: within 1%
    assert errors[0] > errors[1] > errors[2]          # and the error falls as edges shrink
    assert errors[1] / errors[2] > 3.0                # at second order (a ratio of ~4 per halving)


def linear_beam(scene):
    w = scene.omega_T
    L, EI, Rd = scene.flagellum.length, bending_stiffness(scene), scene.R_d
    eta_t, eta_p = rft_coefficients(scene)
    p_t = eta_p * w * Rd                        # paper Eq. linearunitFx
    w_L = p_t * L ** 4 / (8 * EI)                     # Eq. deflection at y = L
    F_p = (eta_p - eta_t) * w * Rd * w_L  # Eq. Fp_linear_solution with v_h = 0
    F_x = p_t * L                                     # Eq. linearFx
    return w_L, F_p, F_x


@pytest.fixture(scope="module")
def clamped_linear(clamped_design2):
    """Design 2's flagellum at 1 rpm: omega_bar = 0.39 <= 0.5, the linear regime."""
    return clamped_design2(1)


def test_clamped_flagellum_is_in_the_linear_regime(clamped_linear):
    sc, out = clamped_linear
    assert normalise_omega(sc, sc.omega_T) <= 0.5
    assert out["steady"]


def test_clamped_flagellum_matches_linear_beam_theory(clamped_linear):
    sc, out = clamped_linear
    w_L, F_p, F_x = linear_beam(sc)
    tip = np.array(out["tip"])
    # the tip lags the clamp (negative z in the co-rotating frame for a positive rotation) by w(L)
    assert abs(-tip[2] / w_L - 1.0) < 0.03
    # the medium pushes the flagellum towards the head (-x): the propulsive force F_p of the paper
    assert out["Fx"] < 0 and abs(-out["Fx"] / F_p - 1.0) < 0.03
    # and resists the rotation with the torque R_d * F_x
    assert out["Tx"] < 0 and abs(-out["Tx"] / (sc.R_d * F_x) - 1.0) < 0.03


def test_linear_theory_error_grows_with_omega_bar(clamped_design2):
    """Beyond the linear regime the DER departs from LB: more at omega_bar ~ 4 than at ~ 0.4."""
    errs = []
    for rpm in (1, 10):
        sc, out = clamped_design2(rpm)
        errs.append(abs(-out["tip"][2] / linear_beam(sc)[0] - 1.0))
    assert errs[1] > 5 * errs[0]
