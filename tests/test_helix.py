"""Naturally helical flagella (flagellum.helix_pitch): the rest shape is the discrete helix, it is a zero-force
state of the rod, the springs' derivatives with that natural curvature and twist are exact, and the steady solver
and its stability analysis run on it unchanged."""
import math

import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.elastic import ElasticModel
from flagbot_sim.physics.frames import EdgeFrames
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.network import build_network, helix_angle
from flagbot_sim.physics.steady import SteadySolver, summary
from flagbot_sim.scene import SceneError, load_scene

from fd import fd_gradient, fd_jacobian, rel_err
from test_elastic_derivatives import energy_grad_hess

SHORT = ["flagellum.length=0.04", "flagellum.edge_length=0.004"]


def helix_scene(pitch, n=3, extra=()):
    return load_scene("design1", [f"flagellum.helix_pitch={pitch}", f"robot.n_flagella={n}", *extra])


@pytest.mark.parametrize("pitch", [0.05, -0.03])
def test_the_rest_shape_is_the_helix_through_each_attachment_point(pitch):
    sc = helix_scene(pitch)
    net = build_network(sc)
    R, L = sc.R_d, sc.flagellum.length
    th = helix_angle(R, pitch)
    assert math.tan(th) == pytest.approx(2 * math.pi * R / abs(pitch), rel=1e-12)
    first = net.nodes[net.flagella_nodes[0]]
    for i, nodes in enumerate(net.flagella_nodes):
        x = net.nodes[nodes]
        # coaxial with the robot (x), at the attachment radius, starting on the plate at azimuth 2 pi i / n
        assert np.allclose(np.hypot(x[:, 1], x[:, 2]), R, rtol=1e-12)
        phi = 2 * math.pi * i / sc.robot.n_flagella
        assert np.allclose(x[0], [0.0, R * math.cos(phi), R * math.sin(phi)], atol=1e-15)
        # the flagella are the same helix turned evenly about the axis (phase-shifted by 2 pi / n)
        c, s = math.cos(phi), math.sin(phi)
        assert np.allclose(x, first @ np.array([[1, 0, 0], [0, c, s], [0, -s, c]]), atol=1e-14)
        # the azimuth advances 2 pi per axial pitch, with the pitch's sign (right-handed for P > 0)
        psi = np.unwrap(np.arctan2(x[:, 2], x[:, 1]))
        assert np.allclose(psi - psi[0], 2 * math.pi * x[:, 0] / pitch, atol=1e-12)
        # nodes a fixed arc length apart: the edges are equal chords of the helix, L long in all
        chord = np.linalg.norm(np.diff(x, axis=0), axis=1)
        n_seg = len(chord)
        ds = L / n_seg
        d = ds * math.sin(th) / R                      # azimuth turned per edge
        assert np.allclose(chord, math.hypot(ds * math.cos(th), 2 * R * math.sin(d / 2)), rtol=1e-12)


def test_natural_curvature_and_twist_are_the_discrete_helix():
    """The hinges' rest curvature is the discrete curvature of the helix's chords, 2 tan(phi/2) (phi: the angle
    between consecutive edges), which is kappa ds = sin^2(theta) ds / R to second order; the natural twist
    (the rest reference twist, held as the hinge's frame offset) has the handedness's sign relative to the
    curvature's turning."""
    for pitch in (0.05, -0.05):
        sc = helix_scene(pitch, n=2)
        net = build_network(sc)
        el = ElasticModel(net)
        R, th = sc.R_d, helix_angle(sc.R_d, pitch)
        edges = net.flagella_edges[0]
        x = net.nodes
        e = x[net.edges[edges, 1]] - x[net.edges[edges, 0]]
        t = e / np.linalg.norm(e, axis=1)[:, None]
        phi = np.arccos(np.clip(np.sum(t[:-1] * t[1:], axis=1), -1, 1))
        # interior hinges of flagellum 0: those joining two of its consecutive edges
        pairs = {(int(a), int(b)): h for h, (a, b) in enumerate(net.hinge_edges)}
        hs = np.array([pairs[(int(edges[k]), int(edges[k + 1]))] for k in range(len(edges) - 1)])
        kb = np.hypot(el.kappa_bar[hs, 0], el.kappa_bar[hs, 1])
        assert np.allclose(kb, 2 * np.tan(phi / 2), rtol=1e-10)
        ds = sc.flagellum.length / len(edges)
        assert np.allclose(kb, ds * math.sin(th) ** 2 / R, rtol=(ds / R) ** 2)
        # torsion of the chords: the sign of (e_k x e_k+1) . e_k+2 is the handedness
        torsion = np.einsum("ki,ki->k", np.cross(t[:-2], t[1:-1]), t[2:])
        assert np.all(np.sign(torsion) == np.sign(pitch))
        # at rest every strain equals its natural value: the twist measured with the frame offsets is zero
        k1, k2, tau = el.hinge_strains(net.initial_q(), el.trial_frames(net.initial_q(), el.frames0))
        assert np.allclose(np.stack([k1, k2], 1), el.kappa_bar, atol=1e-14)
        assert np.allclose(tau, el.tau_bar, atol=1e-14)


@pytest.mark.parametrize("scene,extra", [("design1", ["robot.n_flagella=3"]),
                                         ("clamped_flagellum", [])])
def test_at_rest_the_helix_is_a_zero_force_state_and_stays(scene, extra):
    sc = load_scene(scene, ["flagellum.helix_pitch=-0.04", "motor.omega_rpm=0", *SHORT, *extra])
    m = RobotModel(sc)
    s = m.initial_state()
    r = np.zeros(m.ndof)
    m.elastic.accumulate(s.q, m.elastic.trial_frames(s.q, s.frames), r, None)
    # exactly the rest strains: the elastic force is round-off of the stiffest spring, far below the tolerance
    assert m.residual_norm(r) < 1e-6 * m.force_tol
    sim = Simulation(sc)
    x0 = sim.positions().copy()
    for _ in range(30):
        sim.step()
    assert np.abs(sim.positions() - x0).max() < 1e-12 * sc.flagellum.length


@pytest.mark.parametrize("where", ["committed", "away"])
def test_spring_derivatives_with_the_helix_natural_curvature(where):
    sc = load_scene("design1", ["robot.n_flagella=2", "flagellum.length=0.02", "flagellum.edge_length=0.0025",
                                "flagellum.helix_pitch=0.015"])
    net = build_network(sc)
    el = ElasticModel(net)
    interior = net.edge_elastic[net.hinge_edges].all(axis=1)          # hinges between two flagellum edges
    # the helix's natural curvature is really exercised (kappa ds = 0.12 here)
    assert np.hypot(*el.kappa_bar[interior].T).min() > 0.1
    rng = np.random.default_rng(3)
    N = net.n_nodes
    q_c = net.initial_q() + np.concatenate([1e-3 * rng.standard_normal(3 * N), 0.3 * rng.standard_normal(net.n_edges)])
    fr = EdgeFrames.of(el.trial_frames(q_c, el.frames0.copy()))
    q = q_c if where == "committed" else \
        q_c + np.concatenate([2e-3 * rng.standard_normal(3 * N), 0.2 * rng.standard_normal(net.n_edges)])
    E, grad, hess = energy_grad_hess(net, el, fr, net.motor_hinge, 0.37)
    g = grad(q)
    assert np.linalg.norm(g) > 1e-6
    assert rel_err(g, fd_gradient(E, q, 1e-7)) < 1e-6
    H = hess(q)
    assert rel_err(H, fd_jacobian(grad, q, 1e-6)) < 1e-6


def test_steady_jacobian_on_a_helical_robot_matches_finite_differences():
    from test_steady import bordered_point
    sc, m, S, q, wt, U, c = bordered_point("design1", ["flagellum.length=0.03", "robot.n_flagella=2",
                                                       "flagellum.helix_pitch=-0.03"])
    _, A, _ = S.system(q, c, sc.omega_T, wt, U)
    ndof = m.ndof

    def F(z):
        r, _, _ = S.residual(z[:ndof], c, sc.omega_T, z[ndof], z[ndof + 1])
        return np.concatenate([r, z[:ndof][S.gauge]])

    z = np.concatenate([q, [wt, U]])
    A_fd = fd_jacobian(F, z, 1e-7)
    free = np.ones(len(z), bool)
    free[S.fixed] = False
    A = A.toarray()
    assert rel_err(A[np.ix_(free, free)], A_fd[np.ix_(free, free)]) < 1e-6


def test_steady_solver_and_stability_on_a_helical_robot_equal_the_time_stepped_run():
    sc = load_scene("design2", SHORT + ["flagellum.helix_pitch=-0.03", "time.dt=1e-3", "observe.steady_rtol=1e-6",
                                        "observe.steady_window=0.5"])
    sim = Simulation(sc)
    assert sim.run_until_steady(20.0)
    ts = sim.summary()
    m = RobotModel(sc)
    S = SteadySolver(m)
    sol = S.solve(sc.omega_T)
    st = summary(m, sol)
    for k in ("omega_h", "omega_t", "v"):
        assert st[k] == pytest.approx(ts[k], rel=1e-4), k
    # a left-handed helix turned at a positive omega_t pushes the robot head first
    assert st["v"] > 0
    stab = S.stability(sol)
    assert stab.stable and stab.rate < 0 and stab.neutral == 4


@pytest.mark.parametrize("override,words", [
    ("flagellum.helix_pitch=0.005", "turns would overlap"),
    ("flagellum.helix_pitch=0.01", "cannot resolve"),
])
def test_a_helix_its_rod_cannot_make_is_refused(override, words):
    with pytest.raises(SceneError, match=words) as exc:
        load_scene("design1", [override, "flagellum.edge_length=0.02"] if "resolve" in words else [override])
    assert "flagellum.helix_pitch" in str(exc.value)
