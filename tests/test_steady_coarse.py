"""The steady solver's shortcuts: the fine solve started from Richardson's coarse one, the bordered pattern built
once per structure, the stability verdict without eigenvectors. Each must give what the plain path gives."""
import numpy as np
import pytest

from flagbot_sim.physics import error_estimate
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.steady import SteadySolver, _hermite, solve_with_coarse, summary
from flagbot_sim.scene import load_scene


def _solvers(name, overrides):
    sc = load_scene(name, overrides)
    return sc, SteadySolver(RobotModel(sc)), error_estimate.SpaceEstimator(sc)


@pytest.mark.parametrize("name, overrides, keys", [
    ("design1", ["robot.n_flagella=3", "motor.omega_rpm=100"], ("omega_h", "omega_t", "v")),
    ("design2", ["robot.n_flagella=2", "motor.omega_rpm=250", "flagellum.length=0.11"], ("omega_h", "omega_t", "v")),
    ("clamped_flagellum", ["motor.omega_rpm=100"], ("Fx", "Tx")),
])
def test_the_fine_solve_from_the_coarse_one_is_the_equilibrium_from_the_straight_robot(name, overrides, keys):
    sc, S, space = _solvers(name, overrides)
    plain = S.solve(sc.omega_T)
    fine, coarse = solve_with_coarse(SteadySolver(RobotModel(sc)), space.solver, sc.omega_T)
    assert coarse is not None and len(coarse.q) < len(fine.q)
    a, b = summary(S.model, plain), summary(S.model, fine)
    for k in keys:
        assert b[k] == pytest.approx(a[k], rel=1e-5), k
    assert fine.residual <= S.tol
    # the same shape, node by node (not only the same rates)
    N = S.net.n_nodes
    assert np.max(np.abs(fine.q[: 3 * N] - plain.q[: 3 * N])) < 1e-6 * sc.flagellum.length
    # started next to it: fewer Newton iterations than from the straight robot
    assert fine.iterations < plain.iterations
    # the space estimate from the coarse solution handed over equals the one that solves it again
    space.use(coarse)
    handed = space.estimate(summary(S.model, plain))
    again = error_estimate.SpaceEstimator(sc).estimate(summary(S.model, plain))
    for k in handed:
        assert handed[k] == pytest.approx(again[k], rel=1e-6, abs=1e-12), k


def test_no_guess_across_different_robots():
    _, S2, _ = _solvers("design1", ["robot.n_flagella=2"])
    sc3, S3, _ = _solvers("design1", ["robot.n_flagella=3"])
    assert S2.guess_from(S3, S3.solve(sc3.omega_T)) is None


def test_hermite_interpolation_passes_through_the_points_and_keeps_a_line_straight():
    s = np.linspace(0.0, 1.0, 7)
    y = np.stack([np.sin(3 * s), s ** 3, 1.0 - 2.0 * s], axis=1)
    assert np.allclose(_hermite(s, y, s), y, atol=1e-14)
    t = np.linspace(0.0, 1.0, 23)
    assert np.allclose(_hermite(s, y, t)[:, 2], 1.0 - 2.0 * t, atol=1e-14)
    # a smooth curve: several times closer than the chords (np.interp)
    cubic = np.max(np.abs(_hermite(s, y, t)[:, 0] - np.sin(3 * t)))
    chords = np.max(np.abs(np.interp(t, s, y[:, 0]) - np.sin(3 * t)))
    assert cubic < 0.25 * chords


def test_the_bordered_pattern_is_shared_by_robots_of_one_structure_only():
    _, a, _ = _solvers("design1", ["motor.omega_rpm=50"])
    _, b, _ = _solvers("design1", ["motor.omega_rpm=200"])
    _, c, _ = _solvers("design1", ["robot.n_flagella=3"])
    assert a._pattern is b._pattern and a._pattern is not c._pattern


def test_the_verdict_without_eigenvectors_is_the_verdict_with_them():
    sc, S, _ = _solvers("design2", ["robot.n_flagella=3"])
    sol = S.solve(sc.omega_T)
    full, bare = S.stability(sol), S.stability(sol, vectors=False)
    assert (bare.stable, bare.neutral) == (full.stable, full.neutral)
    assert bare.rate == pytest.approx(full.rate, rel=1e-8)
    assert sorted(abs(m) for m in bare.rates) == pytest.approx(sorted(abs(m) for m in full.rates), rel=1e-8)
    assert bare.twist_shares == [] and np.isnan(bare.shape_rate)


@pytest.mark.parametrize("name, overrides", [("design1", ["robot.n_flagella=3"]), ("clamped_flagellum", [])])
def test_the_factorisation_in_the_patterns_column_order_solves_the_jacobian_with_less_fill(name, overrides):
    """The bordered pattern's fill-reducing column order, found once from the structure, factorises the steady
    Jacobian: the solution of SuperLU's own COLAMD ordering to round-off, with fewer entries in L and U."""
    import scipy.sparse.linalg as spla
    sc, S, _ = _solvers(name, overrides)
    q, w, U = S.initial_guess(sc.omega_T)
    _, A, _ = S.system(q, S.model.elastic.frames0.copy(), sc.omega_T, w, U)
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    lu = S._pattern.factor(A)
    x = lu.solve(b)
    assert sorted(S._pattern.order) == list(range(A.shape[0]))
    plain = spla.splu(A, permc_spec="COLAMD")
    y = plain.solve(b)
    # the Jacobian is badly scaled (stretching against drag): backward errors, and both solutions alike
    scale = abs(A).sum(axis=1).max() * np.abs(x).max()
    assert np.abs(A @ x - b).max() < 1e-13 * scale
    assert np.abs(A @ x - b).max() < 10.0 * max(np.abs(A @ y - b).max(), 1e-15 * scale)
    assert np.abs(x - y).max() < 1e-6 * np.abs(y).max()
    assert lu.lu.L.nnz + lu.lu.U.nnz < plain.L.nnz + plain.U.nnz


@pytest.mark.parametrize("name, overrides", [("design2", ["robot.n_flagella=3"]), ("clamped_flagellum", [])])
def test_the_linearisation_assembled_on_the_pattern_is_the_sparse_products(name, overrides):
    """D = Kv + Ka C bordered by Ka dv/domega_t and Ka dv/dU (free robot), and Mm = Ka, both without the prescribed
    rows, assembled on the bordered pattern: the same matrices as the sparse products, and the pattern shared by
    every robot of the structure is left as it was."""
    import scipy.sparse as sp
    sc, S, _ = _solvers(name, overrides)
    sol = S.solve(sc.omega_T)
    pat = S._pattern
    indices, indptr = pat.indices.copy(), pat.indptr.copy()
    A, D, Mm, _ = S.linearization(sol)
    assert np.array_equal(pat.indices, indices) and np.array_equal(pat.indptr, indptr)
    lin = S._linear(sol.q, sol.frames, sol.omega_T, sol.omega_t, -sol.v)
    ndof, n = S.model.ndof, A.shape[0]
    Kv, Ka = S.model.pattern.matrix(lin.Kv), S.model.pattern.matrix(lin.Ka)
    coriolis = lin.dv_vals.copy()
    coriolis[: 2 * S.N] *= 2.0
    C = sp.csc_matrix((coriolis, (pat.dv_rows, pat.dv_cols)), shape=(ndof, ndof))
    keep = np.ones(n)
    keep[S.fixed] = 0.0
    ref_D = np.zeros((n, n))
    ref_D[:ndof, :ndof] = (Kv + Ka @ C).toarray()
    if n > ndof:
        _, _, dv_dw, _, dv_dU = lin.fields
        ref_D[:ndof, ndof], ref_D[:ndof, ndof + 1] = Ka @ dv_dw, Ka @ dv_dU
    ref_M = np.zeros((n, n))
    ref_M[:ndof, :ndof] = Ka.toarray()
    for got, ref in ((D, ref_D), (Mm, ref_M)):
        ref = keep[:, None] * ref
        assert np.abs(got.toarray() - ref).max() <= 1e-12 * np.abs(ref).max()
        assert got.nnz == np.count_nonzero(ref)


def test_arpack_gets_the_tuned_krylov_space(monkeypatch):
    """The stability analysis asks ARPACK for ARNOLDI_VECTORS Lanczos/Arnoldi vectors (scipy's default 2k + 1
    restarts more often: 13% more operator applications over the sweep grids)."""
    from flagbot_sim.physics import steady
    sc, S, _ = _solvers("design2", ["robot.n_flagella=2"])
    sol = S.solve(sc.omega_T)
    seen = []
    eigs = steady.spla.eigs

    def spy(op, k, **kw):
        seen.append(kw.get("ncv"))
        return eigs(op, k=k, **kw)
    monkeypatch.setattr(steady.spla, "eigs", spy)
    st = S.stability(sol, vectors=False)
    assert seen and seen[0] == steady.ARNOLDI_VECTORS and st.neutral == 4


def test_models_of_one_structure_share_their_sparse_pattern_and_evaluate_the_same():
    """RobotModel takes its Jacobian pattern from assembly.shared_pattern: built once per block structure (~0.8 ms
    a model), the same object for every model of the structure, another for another structure; a model built on
    the shared pattern evaluates exactly as one built on its own."""
    from flagbot_sim.physics import assembly
    a = RobotModel(load_scene("design1", ["motor.omega_rpm=50"]))
    b = RobotModel(load_scene("design1", ["motor.omega_rpm=200"]))
    c = RobotModel(load_scene("design1", ["robot.n_flagella=3"]))
    assert a.pattern is b.pattern and a.pattern is not c.pattern
    S = SteadySolver(b)
    sc = b.scene
    q, w, U = S.initial_guess(sc.omega_T)
    r1, A1, _ = S.system(q, b.elastic.frames0.copy(), sc.omega_T, w, U)
    assembly._PATTERNS.clear()
    own = RobotModel(load_scene("design1", ["motor.omega_rpm=200"]))
    assert own.pattern is not b.pattern
    S2 = SteadySolver(own)
    r2, A2, _ = S2.system(q, own.elastic.frames0.copy(), sc.omega_T, w, U)
    assert np.array_equal(r1, r2) and np.array_equal(A1.toarray(), A2.toarray())


def test_newton_assembles_straight_into_the_factorisation_order_and_evaluates_the_effects_once_less(monkeypatch):
    """Newton's Jacobian is assembled into the factorisation's column order (values(ordered=True)): each entry the
    same sum as the matrix in the unknowns' order, so the same factors; and the springs are added to the effects'
    part already evaluated (residual_and_jacobian(effects_jacobian=...)), the same numbers as evaluating it anew:
    three evaluations of the effects' Jacobians per Newton Jacobian instead of four."""
    sc, S, _ = _solvers("design2", ["robot.n_flagella=3", "motor.omega_rpm=100"])
    model = S.model
    q, w, U = S.initial_guess(sc.omega_T)
    fr = model.elastic.trial_frames(q, model.elastic.frames0.copy())
    fields = S.fields(q, fr.t, sc.omega_T, w, U)
    ctx = S._context(q, fr, fields[0], fields[1], 0.0, 0.0)
    r0, J0 = model.residual_and_jacobian(ctx)
    r1, J1 = model.residual_and_jacobian(ctx, effects_jacobian=model.jacobian(ctx, springs=False))
    assert np.array_equal(r0, r1) and np.array_equal(J0, J1)
    lin = S._linear(q, model.elastic.frames0.copy(), sc.omega_T, w, U)
    A = S._assemble(lin)
    _, _, dv_dw, da_dw, dv_dU = lin.fields
    ordered = S._pattern.values(lin.J00, lin.Kv, lin.Ka, lin.dv_vals, lin.da_vals, dv_dw, da_dw, dv_dU, ordered=True)
    assert np.array_equal(ordered, A.data[S._pattern.order_slots])
    b = np.random.default_rng(2).standard_normal(A.shape[0])
    arrow, S._arrow = S._arrow, None                   # SuperLU's factorisation (numerics.linear_solver = 'splu')
    assert np.array_equal(S._factor(lin).solve(b), S._pattern.factor(A).solve(b))
    S._arrow = arrow
    calls = []
    effect = model.effects[0]
    add_jacobian = effect.add_jacobian

    def counting(ctx, J):
        calls.append((ctx.dv_dq, ctx.da_dq))
        return add_jacobian(ctx, J)
    monkeypatch.setattr(effect, "add_jacobian", counting)
    S._linear(q, model.elastic.frames0.copy(), sc.omega_T, w, U)
    assert calls == [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)]


@pytest.mark.parametrize("name, overrides", [("design1", ["robot.n_flagella=3", "motor.omega_rpm=100"]),
                                             ("design2", ["robot.n_flagella=2", "motor.omega_rpm=200"]),
                                             ("clamped_flagellum", ["motor.omega_rpm=100"])])
def test_newton_and_the_stability_factorise_with_the_arrow_solver(name, overrides, monkeypatch):
    """The steady Jacobian (bordered by omega_t and U and the gauge rows, or the clamped flagellum's with identity
    rows) is factorised by linsolve's arrow solver, compiled (~3x faster than SuperLU): its solutions are
    SuperLU's to round-off (backward errors alike), its interpreted twin's (a cold cache) to the last bit, and the
    equilibrium and the stability verdict are the same as with SuperLU."""
    from flagbot_sim.physics import linsolve, tiers, warmup
    warmup.ensure_compiled(groups=["arrow"])
    sc, S, _ = _solvers(name, overrides)
    assert isinstance(S._arrow, linsolve.ArrowSolver)
    q, w, U = S.initial_guess(sc.omega_T)
    lin = S._linear(q, S.model.elastic.frames0.copy(), sc.omega_T, w, U)
    A = S._assemble(lin)
    lu = S._factor(lin)
    assert lu is S._arrow
    b = np.random.default_rng(3).standard_normal(A.shape[0])
    x = lu.solve(b)
    y = S._pattern.factor(A).solve(b)
    scale = abs(A).sum(axis=1).max() * np.abs(y).max()
    assert np.abs(A @ x - b).max() < 10.0 * max(np.abs(A @ y - b).max(), 1e-15 * scale)
    assert np.abs(x - y).max() < 1e-6 * np.abs(y).max()
    monkeypatch.setattr(tiers, "DEFERRED", {"arrow"})          # the interpreted twins: the same factors
    monkeypatch.setattr(warmup, "swap_in", lambda: False)
    assert np.array_equal(S._factor(lin).solve(b), x)
    monkeypatch.undo()
    # the equilibrium and the stability: SuperLU's to round-off
    sol = S.solve(sc.omega_T)
    st = S.stability(sol, vectors=False)
    ref = SteadySolver(RobotModel(load_scene(name, overrides + ["numerics.linear_solver='splu'"])))
    assert ref._arrow is None
    rsol = ref.solve(sc.omega_T)
    rst = ref.stability(rsol, vectors=False)
    assert np.abs(sol.q - rsol.q).max() <= 1e-9 * np.abs(rsol.q).max()
    assert sol.omega_t == pytest.approx(rsol.omega_t, rel=1e-12, abs=1e-300)
    assert sol.v == pytest.approx(rsol.v, rel=1e-9, abs=1e-15)
    assert (st.stable, st.neutral) == (rst.stable, rst.neutral)
    # the slowest rate to ARPACK's tolerance (1e-10) relative to its mode's |mu|: the clamped flagellum's slowest
    # mode is a twist oscillation, mu = -0.32 + 283i, whose real part moves by 2e-7 relative between SuperLU's
    # own column orders (COLAMD, MMD) and by 3e-8 here
    slowest = next(m for m in rst.rates if m.real == rst.rate)
    assert abs(st.rate - rst.rate) <= 1e-9 * abs(slowest)
