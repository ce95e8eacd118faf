"""The viscous medium (medium.model = 'viscous'): its coefficients are the published closed forms, the model uses
them, every run and steady JSON reports them, and the simulator reproduces the closed forms of a rotating rigid
helix and the independent rod BVP of a flexible straight one in the fluid."""
import json
import math

import pytest

from flagbot_sim.physics import medium
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.steady import SteadySolver, summary
from flagbot_sim.reference.rod_bvp import from_scene, solve_clamped_rod
from flagbot_sim.scene import SceneError, load_scene

from cli_helpers import flagbot

VISCOUS = ["medium.model=viscous", "medium.mu=1.2"]          # glycerin-like, Pa s


def test_coefficients_are_the_published_formulas():
    # the paper's granular RFT, unchanged: effective mu, the straight-rod forms in L, head law with C1, C2
    sc = load_scene("design1")
    L, r0, mu, R = sc.flagellum.length, sc.flagellum.radius, sc.medium.mu, sc.head.radius
    assert sc.medium.model == "granular_rft"
    assert medium.rft_coefficients(sc)[0] == pytest.approx(2 * math.pi * mu / (math.log(2 * L / r0) - 0.5), rel=1e-14)
    assert medium.rft_coefficients(sc)[1] == pytest.approx(4 * math.pi * mu / (math.log(2 * L / r0) + 0.5), rel=1e-14)
    assert medium.head_drag_coefficient(sc) == pytest.approx(sc.head.C1 * 6 * math.pi * mu * R, rel=1e-14)
    # a straight rod in a fluid: Gray & Hancock (1955) with the length L as the wavelength
    sc = load_scene("design1", VISCOUS)
    mu = 1.2
    assert medium.rft_formula(sc) == "gray_hancock_1955"
    assert medium.rft_coefficients(sc)[0] == pytest.approx(2 * math.pi * mu / (math.log(2 * L / r0) - 0.5), rel=1e-14)
    assert medium.rft_coefficients(sc)[1] == pytest.approx(4 * math.pi * mu / (math.log(2 * L / r0) + 0.5), rel=1e-14)
    # the exact Stokes sphere: C1 and C2 (the granular fit) do not enter
    assert medium.head_drag_coefficient(sc) == pytest.approx(6 * math.pi * mu * R, rel=1e-14)
    assert medium.head_torque_coefficient(sc) == pytest.approx(8 * math.pi * mu * R ** 3, rel=1e-14)
    assert medium.head_drag_coefficient(load_scene("design1", VISCOUS + ["head.C1=7", "head.C2=3"])) == \
        medium.head_drag_coefficient(sc)
    # a helix in a fluid: Lighthill (1976), q = 0.09 x the arc length of one turn
    P = -0.05
    sc = load_scene("design1", VISCOUS + [f"flagellum.helix_pitch={P}"])
    Lam = math.sqrt(P ** 2 + (2 * math.pi * sc.R_d) ** 2)
    q = 0.09 * Lam
    assert medium.rft_formula(sc) == "lighthill_1976"
    assert medium.rft_coefficients(sc)[0] == pytest.approx(2 * math.pi * mu / math.log(2 * q / r0), rel=1e-14)
    assert medium.rft_coefficients(sc)[1] == pytest.approx(4 * math.pi * mu / (math.log(2 * q / r0) + 0.5),
                                                           rel=1e-14)
    # and the model's effects use exactly these
    m = RobotModel(sc)
    assert (m.effect("rft").eta_t, m.effect("rft").eta_p) == medium.rft_coefficients(sc)
    assert m.effect("head_drag").c == medium.head_drag_coefficient(sc)
    assert m.effect("head_torque").c == medium.head_torque_coefficient(sc)


def test_free_robot_in_the_fluid_balances_the_exact_stokes_torque():
    sc = load_scene("design2", VISCOUS + ["flagellum.length=0.04", "flagellum.helix_pitch=-0.02"])
    m = RobotModel(sc)
    st = summary(m, SteadySolver(m).solve(sc.omega_T))
    assert st["v"] > 0
    assert st["motor_torque"] == pytest.approx(8 * math.pi * 1.2 * sc.head.radius ** 3 * st["omega_h"], rel=1e-6)
    eta_t, eta_n = medium.rft_coefficients(sc)
    assert st["rft_coefficients"] == {"model": "viscous", "formula": "lighthill_1976", "eta_t": eta_t, "eta_n": eta_n}


def test_every_run_and_steady_json_reports_the_coefficients():
    over = ["--set", "flagellum.length=0.05", "--set", "medium.model=viscous", "--set", "medium.mu=1.2"]
    sc = load_scene("design2", [o for o in over if o != "--set"])
    for args in (("steady", "design2", *over, "--json", "--no-stability"),
                 ("run", "design2", *over, "--duration", "0.05", "--json")):
        p = flagbot(*args)
        assert p.returncode == 0, p.stderr
        rc = json.loads(p.stdout)["rft_coefficients"]
        eta_t, eta_n = medium.rft_coefficients(sc)
        assert (rc["eta_t"], rc["eta_n"], rc["model"]) == (pytest.approx(eta_t, rel=1e-12),
                                                           pytest.approx(eta_n, rel=1e-12), "viscous")


def closed_form(sc, omega):
    """Per unit length of a rigid helix turning at omega about its axis (RFT): the axial force
    sign(P) (eta_n - eta_t) omega R sin cos and torque -omega R^2 (eta_t sin^2 + eta_n cos^2), over its length."""
    R, P, L = sc.R_d, sc.flagellum.helix_pitch, sc.flagellum.length
    th = math.atan2(2 * math.pi * R, abs(P))
    s, c = math.sin(th), math.cos(th)
    eta_t, eta_n = medium.rft_coefficients(sc)
    Fx = math.copysign(1.0, P) * (eta_n - eta_t) * omega * R * s * c * L
    Tx = -omega * R ** 2 * (eta_t * s ** 2 + eta_n * c ** 2) * L
    return Fx, Tx


def test_stiff_clamped_helix_as_users_run_it_matches_the_closed_forms():
    over = ["flagellum.helix_pitch=-0.05", "flagellum.youngs_modulus=1e9", "medium.model=viscous", "medium.mu=1.2",
            "motor.omega_rpm=30"]
    p = flagbot("steady", "clamped_flagellum", *[a for o in over for a in ("--set", o)], "--json",
                "--no-stability")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    Fx, Tx = closed_form(load_scene("clamped_flagellum", over), out["omega_T"])
    assert out["Fx"] == pytest.approx(Fx, rel=1e-2)
    assert out["Tx"] == pytest.approx(Tx, rel=1e-2)


@pytest.mark.parametrize("pitch,rpm", [(0.05, 60.0), (-0.03, 10.0), (0.12, 100.0)])
def test_stiff_clamped_helix_matches_the_closed_forms(pitch, rpm):
    sc = load_scene("clamped_flagellum", [f"flagellum.helix_pitch={pitch}", "flagellum.youngs_modulus=1e9",
                                          *VISCOUS, f"motor.omega_rpm={rpm}"])
    m = RobotModel(sc)
    st = summary(m, SteadySolver(m).solve(sc.omega_T))
    Fx, Tx = closed_form(sc, sc.omega_T)
    assert st["Fx"] == pytest.approx(Fx, rel=1e-2)
    assert st["Tx"] == pytest.approx(Tx, rel=1e-2)
    # a right-handed helix turned at a positive omega is pushed towards +x (tail first), a left-handed one to -x
    assert math.copysign(1, st["Fx"]) == math.copysign(1, pitch)


def test_flexible_straight_rod_in_the_fluid_matches_the_rod_bvp():
    """Design 1's flagellum in a glycerin-like fluid at 30 rpm (omega_bar ~ 15: strongly bent) against the
    geometrically exact rod, given the Gray-Hancock coefficients written out here."""
    sc = load_scene("clamped_flagellum", VISCOUS + ["motor.omega_rpm=30", "flagellum.edge_length=2.055e-3"])
    L, r0, mu = sc.flagellum.length, sc.flagellum.radius, 1.2
    eta_t = 2 * math.pi * mu / (math.log(2 * L / r0) - 0.5)
    eta_n = 4 * math.pi * mu / (math.log(2 * L / r0) + 0.5)
    assert eta_n * sc.omega_T * L ** 4 / medium.bending_stiffness(sc) > 10
    ref = solve_clamped_rod(L, sc.R_d, medium.bending_stiffness(sc), eta_t, eta_n, sc.omega_T,
                            rho_A=sc.flagellum.density * math.pi * r0 ** 2)
    assert ref.converged
    m = RobotModel(sc)
    st = summary(m, SteadySolver(m).solve(sc.omega_T))
    assert st["Fx"] == pytest.approx(ref.Fx, rel=3e-3)
    assert st["Tx"] == pytest.approx(ref.Tx, rel=3e-3)


def test_the_rod_bvp_refuses_a_helical_scene():
    with pytest.raises(ValueError, match="helix_pitch"):
        from_scene(load_scene("clamped_flagellum", ["flagellum.helix_pitch=0.05"]))


@pytest.mark.parametrize("overrides,key", [
    (VISCOUS + ["scene.effects=['inertia','rft','head_drag','head_torque','motor','granular_yield']"],
     "scene.effects"),
    (VISCOUS + ["flagellum.helix_pitch=0.0065", "plate.diameter=0.0001", "flagellum.edge_length=1e-4"],
     "flagellum.radius"),
    (["medium.model=water"], "medium.model"),
])
def test_a_medium_combined_wrongly_is_refused_naming_the_key(overrides, key):
    with pytest.raises(SceneError) as exc:
        load_scene("design1", overrides)
    assert key in str(exc.value) and "\n" not in str(exc.value)
