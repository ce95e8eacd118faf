"""The elastic force is the exact gradient of the elastic energy, and its Jacobian the exact Hessian.

Checked against central finite differences for each energy separately (stretching, bending, twisting) and for the
whole robot, at the committed configuration and away from it (where the reference frames have been carried by
time-parallel transport, so the holonomy terms matter), with random prestrain so every term is exercised.
"""
import numpy as np
import pytest

from flagbot_sim.physics.elastic import ElasticModel
from flagbot_sim.physics.frames import EdgeFrames
from flagbot_sim.physics.network import build_network
from flagbot_sim.scene import load_scene

from fd import dense_elastic_hessian, elastic_gradient, fd_gradient, fd_jacobian, rel_err


def make(n=3, which=("stretch", "bend", "twist"), seed=0):
    sc = load_scene("design1", [f"robot.n_flagella={n}", "flagellum.length=0.02", "flagellum.edge_length=0.005"])
    net = build_network(sc)
    el = ElasticModel(net)
    rng = np.random.default_rng(seed)
    N = net.n_nodes
    q_c = net.initial_q() + np.concatenate([1e-3 * rng.standard_normal(3 * N), 0.3 * rng.standard_normal(net.n_edges)])
    fr = EdgeFrames.of(el.trial_frames(q_c, el.frames0.copy()))
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


def energy_grad_hess(net, el, fr, twist_hinge=-1, twist_offset=0.0):
    """Energy, gradient and Hessian of the compiled springs (the code the simulator runs), with an optional
    motor-like natural-twist offset on one hinge."""
    def E(q):
        return el.energy(q, el.trial_frames(q, fr), twist_hinge, twist_offset)

    def grad(q):
        return elastic_gradient(el, q, el.trial_frames(q, fr), twist_hinge, twist_offset)

    def hess(q):
        return dense_elastic_hessian(el, q, el.trial_frames(q, fr), twist_hinge, twist_offset)
    return E, grad, hess


@pytest.mark.parametrize("which", [("stretch",), ("bend",), ("twist",), ("stretch", "bend", "twist")])
@pytest.mark.parametrize("where", ["committed", "away"])
def test_gradient_and_hessian_match_finite_differences(which, where):
    net, el, fr, q_c, q_away = make(which=which)
    q = q_c if where == "committed" else q_away
    # the motor's natural-twist offset travels with the evaluation: exercise it on the motor hinge
    E, grad, hess = energy_grad_hess(net, el, fr, net.motor_hinge, 0.37)
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
