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


def elastic_gradient(el, q, frames, twist_hinge=-1, twist_offset=0.0):
    """The elastic energy's gradient at q, from the compiled springs that the simulator runs."""
    g = np.zeros(el.net.ndof)
    el.accumulate(q, frames, g, None, twist_hinge, twist_offset)
    return g


def dense_elastic_hessian(el, q, frames, twist_hinge=-1, twist_offset=0.0):
    """The elastic energy's Hessian at q as a dense matrix, from the compiled springs that the simulator runs
    (scattered into a CSC pattern of their own blocks, then densified).

    ``frames`` are the trial frames at q (``el.trial_frames(q, committed)``).
    """
    from flagbot_sim.physics.assembly import SparsePattern
    pattern = SparsePattern(el.net.ndof, [(el.stretch_dofs, el.stretch_dofs), (el.hinge_dofs, el.hinge_dofs)])
    saved = el.stretch_slots, el.hinge_slots
    el.set_slots(pattern.slots[0], pattern.slots[1])
    try:
        J = np.zeros(pattern.nnz)
        el.accumulate(q, frames, np.zeros(el.net.ndof), J, twist_hinge, twist_offset)
    finally:
        el.stretch_slots, el.hinge_slots = saved
    return pattern.matrix(J).toarray()


def newton_point(sim, noise_seed=None):
    """A point where the stepper would evaluate the residual next: the step of size dt is planned (drive angle
    advanced), and q = q_n + dt v_n (plus 1e-5 Gaussian noise from ``noise_seed``, if given, so that nothing is
    symmetric).

    Returns (model, state, plan, q): ``model.context(q, state, plan)`` is the context the stepper would build.
    """
    m, s, h = sim.model, sim.state, sim.dt
    angle = s.drive_angle + (sim.omega_T * h if m.driver is not None else 0.0)
    plan = sim.stepper.integrator.plan(s, h, angle)
    q = s.q + h * s.v
    if noise_seed is not None:
        q = q + 1e-5 * np.random.default_rng(noise_seed).standard_normal(m.ndof)
    return m, s, plan, q
