"""The direct steady-state solver: the relative equilibrium of the same discrete model the time stepper runs.

Its Jacobian is checked by finite differences; its answer against long time-stepped runs (second-order steps small
enough that their own error is below 1e-4) and against the independent rod BVP; its stability verdict against the
time-stepped dynamics; its failures are loud.
"""
import json
import math

import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.medium import head_torque_coefficient, rft_coefficients
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.steady import SHIFT_FLOOR, ClampedFlagellum, SteadyFailed, SteadySolver, summary
from flagbot_sim.scene import load_scene

from cli_helpers import flagbot
from fd import fd_jacobian, rel_err

SHORT_D2 = ["flagellum.length=0.04", "flagellum.edge_length=0.004"]       # design 2, fast relaxation
D2_CLAMPED = ["flagellum.length=0.089", "medium.mu=2.125", "plate.diameter=0.03"]


def bordered_point(scene, overrides, seed=0):
    sc = load_scene(scene, overrides)
    m = RobotModel(sc)
    S = SteadySolver(m)
    q, wt, _ = S.initial_guess(sc.omega_T)
    rng = np.random.default_rng(seed)
    q = q + 1e-4 * rng.standard_normal(len(q))           # off the equilibrium, nothing symmetric
    committed = m.elastic.frames0.copy()
    S.problem.prepare(q, committed)
    return sc, m, S, q, wt, 2e-5, committed


SPIN = "scene.effects=['inertia','rft','head_drag','head_torque','motor','spin_drag']"
SPIN_CLAMPED = "scene.effects=['inertia','rft','clamp','spin_drag']"


@pytest.mark.parametrize("scene,overrides", [("design1", ["flagellum.length=0.03", "robot.n_flagella=3"]),
                                             ("clamped_flagellum", ["flagellum.length=0.03",
                                                                    "motor.omega_rpm=60"]),
                                             ("design1", ["flagellum.length=0.03", SPIN]),
                                             ("clamped_flagellum", ["flagellum.length=0.03", "motor.omega_rpm=60",
                                                                    SPIN_CLAMPED])])
def test_steady_jacobian_matches_finite_differences(scene, overrides):
    sc, m, S, q, wt, U, c = bordered_point(scene, overrides)
    _, A, _ = S.system(q, c, sc.omega_T, wt, U)
    ndof = m.ndof

    def F(z):
        w, u = S.problem.rates(z[ndof:], sc.omega_T)
        r, _, _ = S.residual(z[:ndof], c, sc.omega_T, w, u)
        return np.concatenate([r, z[:ndof][S.gauge]])

    z = np.concatenate([q, S.problem.pack(wt, U)])
    assert len(z) == ndof + len(S.gauge) == A.shape[0]
    # omega_t and U in units where a step of 1e-7 is a small relative change
    A_fd = fd_jacobian(F, z, 1e-7)
    free = np.ones(len(z), bool)
    free[S.fixed] = False
    A = A.toarray()
    assert rel_err(A[np.ix_(free, free)], A_fd[np.ix_(free, free)]) < 1e-6
    # the columns of the rigid-motion unknowns (free robot), alone: R is quadratic in omega_t and linear in U, so
    # central differences are exact for any step, and a larger one keeps round-off out of these small entries
    for j in range(ndof, len(z)):
        e = np.zeros(len(z))
        e[j] = 1e-3
        col = (F(z + e) - F(z - e)) / 2e-3
        assert rel_err(A[:, j], col) < 1e-8, j


@pytest.fixture(scope="module")
def long_runs():
    """Time-stepped runs from rest to a steady state with BDF2 at dt = 1e-3 s (omega dt = 0.01: its velocity
    error (omega dt)^2 / 3 = 3.7e-5) and the steady solution of the same scene."""
    out = {}
    for key, scene, over in (("free", "design2", SHORT_D2), ("clamped", "clamped_flagellum",
                                                             D2_CLAMPED + SHORT_D2 + ["motor.omega_rpm=100"])):
        sc = load_scene(scene, over + ["time.integrator='bdf2'", "time.dt=1e-3", "observe.steady_rtol=1e-6",
                                       "observe.steady_window=0.5"])
        sim = Simulation(sc)
        assert sim.run_until_steady(20.0), key
        m = RobotModel(sc)
        sol = SteadySolver(m).solve(sc.omega_T)
        out[key] = (sim, sim.summary(), summary(m, sol))
    return out


def test_steady_state_equals_the_long_time_stepped_run(long_runs):
    sim, ts, st = long_runs["free"]
    for k in ("omega_h", "omega_t", "v"):
        assert st[k] == pytest.approx(ts[k], rel=1e-4), k
    assert st["omega_h"] + st["omega_t"] == pytest.approx(st["omega_T"], rel=1e-12)
    sim, ts, st = long_runs["clamped"]
    for k in ("Fx", "Tx"):
        assert st[k] == pytest.approx(ts[k], rel=1e-4), k
    # the tip, in the frame turning with the clamp (the steady solution is seen at drive angle 0)
    assert np.linalg.norm(np.array(st["tip"]) - np.array(ts["tip"])) < 1e-4 * np.linalg.norm(st["tip"])


def test_steady_state_converges_to_the_rod_bvp_as_edges_shrink():
    """Design 1's clamped flagellum at 10 rpm against the geometrically exact rod (with the same centripetal
    load): the error of the discrete model falls with the edge length."""
    from flagbot_sim.reference.rod_bvp import from_scene
    errs = []
    for edge in (8.22e-3, 4.11e-3, 2.055e-3):
        sc = load_scene("clamped_flagellum", [f"flagellum.edge_length={edge}"])
        m = RobotModel(sc)
        st = summary(m, SteadySolver(m).solve(sc.omega_T))
        ref = from_scene(sc)
        errs.append(max(abs(st["Fx"] / ref.Fx - 1), abs(st["Tx"] / ref.Tx - 1)))
    assert errs[0] > errs[1] > errs[2] and errs[2] < 3e-3


def test_stability_agrees_with_the_time_stepped_dynamics(long_runs):
    """The equilibrium the time-stepped run settled in is reported stable, and its slowest decay rate is of the
    order of the run's own approach to it."""
    sc = long_runs["free"][0].scene
    m = RobotModel(sc)
    S = SteadySolver(m)
    st = S.stability(S.solve(sc.omega_T))
    assert st.stable and st.rate < 0
    assert st.neutral == 4        # a sideways shift and a tilt of the whole robot change nothing: neutral


def _rigid(S, sol, rotation=None, shift=None):
    """A rigid rotation (axis through the head centre) or shift of the equilibrium, as a bordered DOF vector
    (positions, and the twist angles' change when their reference frames are transported: n . t)."""
    m, N = S.model, S.N
    x = sol.q[: 3 * N].reshape(N, 3)
    z = np.zeros(m.ndof + 2)
    if rotation is not None:
        c = x[m.net.head_nodes[1]]
        z[: 3 * N] = np.cross(rotation, x - c).ravel()
        z[3 * N: m.ndof] = sol.frames.t @ np.asarray(rotation, float)
    else:
        z[: 3 * N] = np.tile(shift, N)
    return z


@pytest.mark.parametrize("scene,rpm,inertia,spin", [("design1", 250, False, False), ("design2", 150, False, False),
                                                    ("design1", 250, True, False), ("design2", 150, True, False),
                                                    ("design2", 150, True, True)])
def test_the_linearisation_admits_the_tilted_robot(scene, rpm, inertia, spin):
    """A tilted robot swims the same along its tilted axis: in the turning frame, the tilt about e_z turns at
    omega_t (into a tilt about e_y) and the robot drifts sideways at U times the tilt. That motion,
    z(t) = [n(t) x (x - c), t . n(t)] + U t R_x(-omega_t t) e_y with n(t) = R_x(-omega_t t) e_z, solves the
    linearised dynamics A z + D z' + Mm z'' = 0 at t = 0 (z' = omega_t T_y + U S_y, z'' = -omega_t^2 T_z -
    2 U omega_t S_z), to the round-off of the equilibrium: no spurious growth or precession can come out of it
    (before the head torque's work on a moving tangent was counted, design 1 was called unstable above 117 rpm)."""
    effects = "['inertia','rft','head_drag','head_torque','motor']" if inertia else \
        "['rft','head_drag','head_torque','motor']"
    if spin:         # the spin drag's torques about the flagella's turning tangents do work through the holonomy too
        effects = effects[:-1] + ",'spin_drag']"
    sc = load_scene(scene, [f"motor.omega_rpm={rpm}", f"scene.effects={effects}"])
    S = SteadySolver(RobotModel(sc))
    sol = S.solve(sc.omega_T)
    A, D, Mm, w = S.linearization(sol)
    assert (Mm.nnz > 0) == inertia
    ex, ey, ez = np.eye(3)
    Tz, Ty = _rigid(S, sol, rotation=ez), _rigid(S, sol, rotation=ey)
    Sy, Sz = _rigid(S, sol, shift=ey), _rigid(S, sol, shift=ez)
    U = -sol.v
    lhs = A @ Tz
    res = lhs + D @ (w * Ty + U * Sy) + Mm @ (-w * w * Tz - 2 * U * w * Sz)
    assert np.linalg.norm(lhs) > 0
    assert np.linalg.norm(res) < 1e-6 * np.linalg.norm(lhs)
    st = S.stability(sol)
    assert st.stable and st.neutral == 4


@pytest.mark.parametrize("scene,overrides", [("design1", ["flagellum.length=0.05", "motor.omega_rpm=200"]),
                                             ("design1", []),       # ARPACK's last mode was half a complex pair
                                             ("design2", SHORT_D2),
                                             ("clamped_flagellum", [*D2_CLAMPED, "motor.omega_rpm=5000"])])
def test_stability_finds_the_slowest_mode_of_the_whole_spectrum(scene, overrides):
    """ARPACK's modes nearest 0 are exactly those of the whole spectrum (a dense solve of the same pencil
    A z + mu D z + mu^2 Mm z = 0) up to the largest |mu| it examined, and the verdict is that of the slowest of
    them; a free robot's spectrum has exactly four neutral modes, at +-i omega_t (shift and tilt). Design 2's
    clamped flagellum at 5000 rpm is unstable (the centrifugal load whirls it off this branch, as the time
    stepper shows: tests/test_integrators.py), which the overdamped analysis missed."""
    import scipy.linalg as sl
    sc = load_scene(scene, overrides)
    S = SteadySolver(RobotModel(sc))
    sol = S.solve(sc.omega_T)
    A, D, Mm, omega_t = S.linearization(sol)
    n = A.shape[0]
    P = np.block([[A.toarray(), np.zeros((n, n))], [np.zeros((n, n)), np.eye(n)]])
    Q = np.block([[-D.toarray(), -Mm.toarray()], [np.eye(n), np.zeros((n, n))]])
    mu = sl.eig(P, Q, right=False)                                    # P y = mu Q y, y = (z, mu z)
    mu = mu[np.isfinite(mu)]
    st = S.stability(sol)
    found = np.array(st.rates)
    inside = mu[np.abs(mu) <= np.abs(found).max() * (1 + 1e-6)]
    assert len(inside) == len(found)
    # the shift and tilt modes are a double pair at +-i omega_t: a double eigenvalue is known to a dense solver only
    # to ~sqrt(eps) of the matrices' scale (measured: 3.5e-6 relative with numpy 2.4 / scipy 1.17), every simple
    # mode to ~1e-8; ARPACK's answer must be within that of each
    double = (np.abs(inside.real) < 1e-4 * omega_t) & (np.abs(np.abs(inside.imag) - omega_t) < 1e-4 * omega_t)
    tol = np.where(double, 1e-4, 1e-6)
    assert np.all([np.min(np.abs(found - m)) < t * max(1.0, abs(m)) for m, t in zip(inside, tol)])
    if isinstance(S.problem, ClampedFlagellum):
        assert st.neutral == 0 and not st.stable and st.rate == pytest.approx(inside.real.max(), rel=1e-6)
        assert st.rate > 10.0                                        # [41 1/s at 227 rad/s]
    else:
        neutral = (np.abs(mu.real) < 1e-4 * omega_t) & (np.abs(np.abs(mu.imag) - omega_t) < 1e-4 * omega_t)
        assert neutral.sum() == 4 and st.neutral == 4 and st.stable
        rest = inside[~((np.abs(inside.real) < 1e-4 * omega_t) &
                        (np.abs(np.abs(inside.imag) - omega_t) < 1e-4 * omega_t))]
        assert st.rate == pytest.approx(rest.real.max(), rel=1e-6)



@pytest.mark.parametrize("scene", ["design1", "design2"])
def test_a_robot_at_rest_is_stable_with_the_slow_speed_limit_of_its_modes(scene):
    """At omega_T = 0 the shift and tilt modes sit at mu = 0 itself and the steady Jacobian is singular (before:
    a spurious 'grows at 300 1/s'); the modes are then sought about a small negative shift. Nothing grows, the
    four neutral modes are found, and the slowest decay equals its limit from slowly turning robots, where the
    unshifted analysis works."""
    sc = load_scene(scene, ["flagellum.length=0.05"])
    S = SteadySolver(RobotModel(sc))
    at_rest = S.stability(S.solve(0.0))
    slow_sol = S.solve(1.0)
    assert slow_sol.omega_t > 2 * SHIFT_FLOOR                # no shift there
    slow = S.stability(slow_sol)
    assert at_rest.stable and at_rest.neutral == 4 and slow.neutral == 4
    assert at_rest.rate < 0 and at_rest.rate == pytest.approx(slow.rate, rel=1e-3)


def test_an_undamped_twist_oscillation_is_marginal_not_unstable():
    """The clamped flagellum at rest: its twist carries no drag, so its twist modes oscillate undamped (mu on the
    imaginary axis up to round-off, which can put the real part at +1e-12). That is reported as marginally
    stable (rate 0), not as a growing perturbation."""
    sc = load_scene("clamped_flagellum", ["flagellum.length=0.05", "motor.omega_rpm=0"])
    S = SteadySolver(RobotModel(sc))
    st = S.stability(S.solve(0.0))
    mu = np.array(st.rates)
    assert np.any((np.abs(mu.real) <= 1e-8 * np.abs(mu)) & (np.abs(mu.imag) > 1.0))
    assert st.stable and st.rate == 0.0


def test_flagbot_steady_as_users_run_it():
    """`flagbot steady --json` in its own process: every field of `flagbot run --json` for the same scene (one
    schema for both), plus the residual and the stability, in strict JSON; where no equilibrium exists, one
    clear line naming the speed it reached, exit status 1, no traceback."""
    over = ["--set", "flagellum.length=0.05"]
    p = flagbot("steady", "design2", *over, "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    r = flagbot("run", "design2", *over, "--duration", "0.05", "--json")
    assert r.returncode == 0, r.stderr
    missing = set(json.loads(r.stdout)) - set(out)
    assert not missing, missing
    assert out["steps"] == 0 and out["time"] is None and out["residual"] < 1e-7 and out["stability"]["stable"]
    assert 0 < out["startup_seconds"] < 60
    bad = flagbot("steady", "design2", "--set", "robot.n_flagella=5", "--set", "flagellum.youngs_modulus=1e4",
                  "--omega-rpm", "10000", "--no-stability")
    assert bad.returncode == 1 and "Traceback" not in bad.stderr + bad.stdout
    assert "NO EQUILIBRIUM" in bad.stdout and "stalled at omega_T" in bad.stdout


def test_the_first_guess_balances_the_effects_spin_drag():
    """The straight robot's first guess asks the effects for their spin drag (the head's Stokes torque, the
    flagella's RFT n eta_p L R_d^2) and balances it: omega_h c_h = omega_t c_t; without the head torque the head
    takes every turn (nothing resists it), without any drag the turns are split evenly."""
    sc = load_scene("design1", ["robot.n_flagella=3"])
    m = RobotModel(sc)
    c_h, c_t = m.spin_drag()
    eta_p = rft_coefficients(sc)[1]
    assert c_h == pytest.approx(head_torque_coefficient(sc), rel=1e-15)
    assert c_t == pytest.approx(3 * eta_p * sc.flagellum.length * sc.R_d ** 2, rel=1e-15)
    _, omega_t, U = SteadySolver(m).initial_guess(sc.omega_T)
    assert (sc.omega_T - omega_t) * c_h == pytest.approx(omega_t * c_t, rel=1e-12) and 0 < omega_t < sc.omega_T
    assert U == 0.0
    for effects, expected in ((["rft", "head_drag", "motor"], 0.0), (["head_drag", "motor"], 0.5 * sc.omega_T)):
        m = RobotModel(sc.with_overrides({"scene.effects": effects}))
        assert SteadySolver(m).initial_guess(sc.omega_T)[1] == pytest.approx(expected, rel=1e-15, abs=1e-300)


def test_the_stability_report_is_reproducible_to_the_last_digit():
    """Two separate processes report the same eigenvalues bit for bit (ARPACK's start vector is fixed: its own
    random one moved the clamped flagellum's rates by up to 6e-5 relative between runs)."""
    args = ("steady", "clamped_flagellum", "--set", "flagellum.length=0.03", "--set", "motor.omega_rpm=60", "--json")
    a, b = flagbot(*args), flagbot(*args)
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    sa, sb = json.loads(a.stdout)["stability"], json.loads(b.stdout)["stability"]
    assert sa == sb and isinstance(sa["slowest_rate"], float)


def test_gravity_across_the_axis_is_refused_with_its_reason_and_along_it_is_solved():
    """Gravity across the robot's axis turns in the frame turning with the robot: no relative equilibrium exists
    (the solver used to stall at omega_T = 0.01 rad/s and say only that); along the axis it keeps the symmetry."""
    effects = "scene.effects=['inertia','rft','head_drag','head_torque','motor','gravity']"
    sc = load_scene("design1", [effects, "flagellum.length=0.03"])
    with pytest.raises(SteadyFailed, match=r"gravity\.g = \[0\.0, 0\.0, -9\.81\] has a part across the robot's axis"):
        SteadySolver(RobotModel(sc)).solve(sc.omega_T)
    sc = load_scene("design1", [effects, "flagellum.length=0.03", "gravity.g=[-9.81,0,0]"])
    sol = SteadySolver(RobotModel(sc)).solve(sc.omega_T)
    no_g = load_scene("design1", ["flagellum.length=0.03"])
    v0 = SteadySolver(RobotModel(no_g)).solve(no_g.omega_T).v
    assert math.isfinite(sol.v) and sol.v != v0          # its weight along -x changes the swimming speed
