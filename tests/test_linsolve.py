"""The arrow solver (banded flagella + Schur complement of the core, LAPACK LU from compiled code) solves the
Newton system exactly as SuperLU does, and a whole run does not depend on which of the two solves it."""
import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.linsolve import ArrowSolver, SingularJacobian, SparseLU, flagellum_chains
from flagbot_sim.scene import load_scene

from fd import newton_point

CASES = [("design1", ["robot.n_flagella=3"]), ("design2", ["robot.n_flagella=5"]), ("clamped_flagellum", [])]


def moving(scene, overrides, t=0.3):
    sim = Simulation(load_scene(scene, overrides + ["scene.effects=['inertia','rft','head_drag','head_torque',"
                                                    "'motor']"] if scene != "clamped_flagellum" else overrides))
    sim.run(t)
    return (sim, *newton_point(sim, noise_seed=3))


@pytest.mark.parametrize("scene,overrides", CASES)
def test_arrow_solver_solves_the_newton_system(scene, overrides):
    sim, m, s, plan, q = moving(scene, overrides)
    r, data = m.residual_and_jacobian(m.context(q, s, plan))
    st = sim.stepper
    data[st._fix_slots] = 0.0
    data[st._fix_diag] = 1.0
    r[st.fixed] = 0.0
    arrow = ArrowSolver(m.pattern, flagellum_chains(m.net))
    arrow.factor(data)
    x = arrow.solve(r)
    A = m.pattern.matrix(data)
    assert np.abs(A @ x - r).max() <= 1e-12 * np.abs(r).max()
    lu = SparseLU(m.pattern)
    lu.factor(data)
    assert np.allclose(x, lu.solve(r), rtol=1e-6, atol=1e-9 * np.abs(x).max())
    # the factors are reusable: a second right-hand side is solved backward-stably (round-off of |A| |x|)
    b = np.random.default_rng(0).standard_normal(len(r))
    y = arrow.solve(b)
    assert np.abs(A @ y - b).max() <= 1e-13 * (abs(A).sum(axis=1).max() * np.abs(y).max() + np.abs(b).max())


def test_a_singular_jacobian_is_reported_not_solved():
    sim, m, s, plan, q = moving("design1", ["robot.n_flagella=2"])
    arrow = ArrowSolver(m.pattern, flagellum_chains(m.net))
    with pytest.raises(SingularJacobian):
        arrow.factor(np.zeros(m.pattern.nnz))


def test_whole_run_is_the_same_with_either_linear_solver():
    runs = []
    for solver in ("arrow", "splu"):
        sim = Simulation(load_scene("design2", ["flagellum.length=0.05", "motor.omega_rpm=150",
                                                f"numerics.linear_solver='{solver}'"]))
        assert sim.stepper.solver.name == solver
        sim.run(0.5)
        runs.append(sim.state.q.copy())
    assert np.abs(runs[0] - runs[1]).max() < 1e-9


@pytest.mark.parametrize("m,kl,ku,nrhs", [(30, 4, 5, 1), (25, 7, 3, 3), (12, 0, 2, 2), (40, 11, 11, 1), (5, 4, 4, 1)])
def test_the_band_solve_is_lapacks_dgbtrs(m, kl, ku, nrhs):
    """The banded solves with dgbtrf's factors are loops of ours (dgbtrs's algorithm, without its BLAS call per
    column): on random band matrices whose LU pivots, with several right-hand sides and zero entries in them,
    they give LAPACK's dgbtrs's answer to round-off, and solve the system; reading each column of U only as far
    as its farthest nonzero changes no bit."""
    from scipy.linalg import lapack
    from flagbot_sim.physics.linsolve import _band_solve, _u_extents
    rng = np.random.default_rng(m + kl + ku)
    A = np.zeros((m, m))
    for i in range(m):
        for j in range(max(0, i - kl), min(m, i + ku + 1)):
            A[i, j] = rng.standard_normal()
    ldab = 2 * kl + ku + 1
    ab = np.zeros((ldab, m))
    for j in range(m):
        for i in range(max(0, j - ku), min(m, j + kl + 1)):
            ab[kl + ku + i - j, j] = A[i, j]
    lu, piv, info = lapack.dgbtrf(ab, kl, ku)
    assert info == 0 and (kl == 0 or np.any(piv != np.arange(m)))          # it pivoted
    B = rng.standard_normal((m, nrhs))
    B[::4] = 0.0
    ref, info = lapack.dgbtrs(lu, kl, ku, B, piv)
    buf = np.concatenate([np.zeros(3), lu.ravel(order="F")])               # the band at an offset, as in buf
    ipiv = np.concatenate([np.zeros(2, np.int32), (piv + 1).astype(np.int32)])
    ext = np.zeros(2 + m, np.int64)
    _u_extents.py_func(buf, 3, ldab, m, kl, ku, ext, 2)
    full = np.concatenate([np.zeros(2, np.int64), np.minimum(np.arange(m), kl + ku)])   # every superdiagonal
    assert np.all(ext <= full) and (kl == 0 or m < 2 * (kl + ku) or np.any(ext < full))
    rhs = np.concatenate([np.zeros(1), B.ravel(order="F")])
    rhs_full = rhs.copy()
    _band_solve.py_func(buf, 3, ldab, m, kl, ku, ipiv, 2, rhs, 1, nrhs, ext)
    _band_solve.py_func(buf, 3, ldab, m, kl, ku, ipiv, 2, rhs_full, 1, nrhs, full)
    assert np.array_equal(rhs, rhs_full)            # what the extents leave out is exact zeros
    x = rhs[1:].reshape((m, nrhs), order="F")
    assert np.allclose(x, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    assert np.abs(A @ x - B).max() <= 1e-12 * (np.abs(A).sum(axis=1).max() * np.abs(x).max() + np.abs(B).max())
