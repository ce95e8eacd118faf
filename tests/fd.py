"""Finite-difference helpers shared by the derivative tests."""
import numpy as np


def fd_gradient(f, x, h=1e-7):
    g = np.zeros_like(x)
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        g[i] = (f(x + e) - f(x - e)) / (2 * h)
    return g


def fd_jacobian(F, x, h=1e-7):
    cols = []
    for i in range(len(x)):
        e = np.zeros_like(x)
        e[i] = h
        cols.append((F(x + e) - F(x - e)) / (2 * h))
    return np.array(cols).T


def rel_err(a, b):
    return np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300)


def dense_elastic_hessian(el, q, frames):
    """The elastic energy's Hessian at q as a dense matrix: the stretch and hinge blocks scattered into place.

    ``frames`` are the trial frames at q (``el.trial_frames(q, committed)``).
    """
    _, hs = el.stretch_terms(frames, True)
    _, hh = el.hinge_terms(q, frames, True)
    H = np.zeros((el.net.ndof, el.net.ndof))
    for k in range(len(hs)):
        H[np.ix_(el.stretch_dofs[k], el.stretch_dofs[k])] += hs[k]
    for k in range(len(hh)):
        H[np.ix_(el.hinge_dofs[k], el.hinge_dofs[k])] += hh[k]
    return H


def newton_point(sim, noise_seed=None):
    """A point where the stepper would evaluate the residual next: the drivers have begun the step, and
    q = q_n + dt v_n (plus 1e-5 Gaussian noise from ``noise_seed``, if given, so that nothing is symmetric).

    Returns (model, state, dt, q).
    """
    m, s, h = sim.model, sim.state, sim.dt
    for d in sim.stepper._drivers:
        d.begin_step(s, h)
    q = s.q + h * s.v
    if noise_seed is not None:
        q = q + 1e-5 * np.random.default_rng(noise_seed).standard_normal(m.ndof)
    return m, s, h, q
