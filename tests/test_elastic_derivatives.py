"""The elastic force is the exact gradient of the elastic energy, and its Jacobian the exact Hessian.

Checked against central finite differences for each energy separately (stretching, bending, twisting) and for the
whole robot, at the committed configuration and away from it (where the reference frames have been carried by
time-parallel transport, so the holonomy terms matter), with random prestrain so every term is exercised.
"""
import numpy as np
import pytest

from flagbot_sim.physics.elastic import ElasticModel
from flagbot_sim.physics.network import build_network
from flagbot_sim.scene import load_scene

from fd import dense_elastic_hessian, fd_gradient, fd_jacobian, rel_err


def make(n=3, which=("stretch", "bend", "twist"), seed=0):
    sc = load_scene("design1", [f"robot.n_flagella={n}", "flagellum.length=0.02", "flagellum.edge_length=0.005"])
    net = build_network(sc)
    el = ElasticModel(net)
    rng = np.random.default_rng(seed)
    N = net.n_nodes
    q_c = net.initial_q() + np.concatenate([1e-3 * rng.standard_normal(3 * N), 0.3 * rng.standard_normal(net.n_edges)])
    fr = el.frames0.copy()
    tf = el.trial_frames(q_c, fr)
    fr.commit(tf.t, tf.d1, tf.d2, tf.ref_twist)
    el.tau_bar = el.tau_bar + 0.2 * rng.standard_normal(el.tau_bar.shape)
    el.kappa_bar = el.kappa_bar + 0.1 * rng.standard_normal(el.kappa_bar.shape)
    if "stretch" not in which:
        net.EA[:] = 0.0
    if "bend" not in which:
        el.k_bend = el.k_bend * 0.0
    if "twist" not in which:
        el.k_twist = el.k_twist * 0.0
    q_away = q_c + np.concatenate([2e-3 * rng.standard_normal(3 * N), 0.2 * rng.standard_normal(net.n_edges)])
    return net, el, fr, q_c, q_away


def energy_grad_hess(net, el, fr):
    def E(q):
        return el.energy(q, el.trial_frames(q, fr))

    def grad(q):
        f = el.trial_frames(q, fr)
        g = np.zeros(net.ndof)
        gs, _ = el.stretch_terms(f, False)
        gh, _ = el.hinge_terms(q, f, False)
        np.add.at(g, el.stretch_dofs, gs)
        np.add.at(g, el.hinge_dofs, gh)
        return g

    def hess(q):
        return dense_elastic_hessian(el, q, el.trial_frames(q, fr))
    return E, grad, hess


@pytest.mark.parametrize("which", [("stretch",), ("bend",), ("twist",), ("stretch", "bend", "twist")])
@pytest.mark.parametrize("where", ["committed", "away"])
def test_gradient_and_hessian_match_finite_differences(which, where):
    net, el, fr, q_c, q_away = make(which=which)
    q = q_c if where == "committed" else q_away
    E, grad, hess = energy_grad_hess(net, el, fr)
    g = grad(q)
    assert np.linalg.norm(g) > 1e-6, "prestrain must make the gradient non-trivial"
    assert rel_err(g, fd_gradient(E, q, 1e-7)) < 1e-6
    H = hess(q)
    H_fd = fd_jacobian(grad, q, 1e-6)
    assert rel_err(H, H_fd) < 1e-6
    # the Hessian of an energy is symmetric: the finite-difference Jacobian of the force must be too
    assert rel_err(H_fd, H_fd.T) < 1e-6


def test_energy_second_differences_give_the_same_hessian():
    """Independent of the gradient code: mixed second differences of the energy itself."""
    net, el, fr, q_c, q_away = make(n=2)
    E, _, hess = energy_grad_hess(net, el, fr)
    H = hess(q_away)
    rng = np.random.default_rng(1)
    idx = rng.choice(net.ndof, size=12, replace=False)
    h = 1e-5
    D2 = np.zeros((len(idx), len(idx)))
    for a, i in enumerate(idx):
        for b, j in enumerate(idx):
            ei = np.zeros(net.ndof)
            ej = np.zeros(net.ndof)
            ei[i] = h
            ej[j] = h
            D2[a, b] = (E(q_away + ei + ej) - E(q_away + ei - ej) - E(q_away - ei + ej)
                        + E(q_away - ei - ej)) / (4 * h * h)
    assert rel_err(H[np.ix_(idx, idx)], D2) < 1e-4
