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
