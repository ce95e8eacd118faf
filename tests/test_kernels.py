"""The compiled kernels and the arrow solver compute exactly what the numpy reference and SuperLU compute."""
import numpy as np
import pytest

from flagbot_sim.physics import Simulation, kernels
from flagbot_sim.physics.linsolve import ArrowSolver, SparseLU, flagellum_chains
from flagbot_sim.scene import load_scene

from fd import newton_point

# only the compiled cases: the numpy path (the arrow solver's included) is what runs when numba is missing
needs_kernels = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba not installed: only the numpy path exists")

CASES = [("design1", ["robot.n_flagella=3"]), ("design2", ["robot.n_flagella=5"]), ("clamped_flagellum", [])]


def moving(scene, overrides, t=0.3):
    sim = Simulation(load_scene(scene, overrides + ["scene.effects=['inertia','rft','head_drag','head_torque',"
                                                    "'motor']"] if scene != "clamped_flagellum" else overrides))
    sim.run(t)
    return (sim, *newton_point(sim, noise_seed=3))


@needs_kernels
@pytest.mark.parametrize("scene,overrides", CASES)
def test_compiled_residual_and_jacobian_equal_numpy(scene, overrides):
    sim, m, s, h, q = moving(scene, overrides)
    r_k, d_k, c_k = m.residual_and_jacobian(q, s, h)
    m.elastic.use_kernels = False
    for e in m.effects:
        e.use_kernels = False
    r_n, d_n, c_n = m.residual_and_jacobian(q, s, h)
    assert np.abs(c_k.frames.d1 - c_n.frames.d1).max() < 1e-14
    assert np.abs(c_k.frames.ref_twist - c_n.frames.ref_twist).max() < 1e-13
    assert np.abs(r_k - r_n).max() <= 1e-13 * np.abs(r_n).max()
    assert np.abs(d_k - d_n).max() <= 1e-13 * np.abs(d_n).max()


@pytest.mark.parametrize("scene,overrides", CASES)
@pytest.mark.parametrize("compiled", [pytest.param(True, marks=needs_kernels), False])
def test_arrow_solver_solves_the_newton_system(scene, overrides, compiled):
    sim, m, s, h, q = moving(scene, overrides)
    r, data, _ = m.residual_and_jacobian(q, s, h)
    st = sim.stepper
    data[st._fix_slots] = 0.0
    data[st._fix_diag] = 1.0
    r[st.fixed] = 0.0
    arrow = ArrowSolver(m.pattern, flagellum_chains(m.net))
    arrow.compiled = compiled
    arrow.factor(data)
    x = arrow.solve(r)
    A = m.pattern.matrix(data)
    assert np.abs(A @ x - r).max() <= 1e-12 * np.abs(r).max()
    lu = SparseLU(m.pattern)
    lu.factor(data)
    assert np.allclose(x, lu.solve(r), rtol=1e-6, atol=1e-9 * np.abs(x).max())


@needs_kernels
def test_whole_run_is_the_same_with_and_without_kernels():
    runs = []
    for compiled in (True, False):
        sim = Simulation(load_scene("design2", ["flagellum.length=0.05", "motor.omega_rpm=150"]))
        sim.model.elastic.use_kernels = compiled
        for e in sim.model.effects:
            if hasattr(e, "use_kernels"):
                e.use_kernels = compiled
        sim.stepper.solver.compiled = compiled
        sim.run(0.5)
        runs.append(sim.state.q.copy())
    assert np.abs(runs[0] - runs[1]).max() < 1e-9
