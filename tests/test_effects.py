"""Every effect's Jacobian agrees with finite differences, and scenes build exactly the effects they list."""
import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.scene import load_scene

from fd import fd_jacobian, newton_point, rel_err

ALL_FREE = "['inertia','rft','head_drag','head_torque','motor','gravity']"


def dense_effect_jacobian(model, eff, jac_values):
    blocks = eff.blocks()
    J = np.zeros((model.ndof, model.ndof))
    for (r, c), v in zip(blocks, jac_values):
        v = np.broadcast_to(v, (r.shape[0], r.shape[1], c.shape[1]))
        for k in range(r.shape[0]):
            J[np.ix_(r[k], c[k])] += v[k]
    return J


def moving_robot(scene="design1", extra=()):
    sc = load_scene(scene, ["robot.n_flagella=2", "flagellum.length=0.03", f"scene.effects={ALL_FREE}", *extra])
    sim = Simulation(sc)
    for _ in range(15):
        sim.step()
    return sim


@pytest.mark.parametrize("name", ["inertia", "rft", "head_drag", "head_torque", "gravity"])
def test_effect_jacobian_matches_finite_differences(name):
    m, s, h, q = newton_point(moving_robot(), noise_seed=2)
    eff = m.effect(name)

    def F(qq):
        out = np.zeros(m.ndof)
        i, f = eff.force(m.context(qq, s, h))
        np.add.at(out, np.ravel(i), np.ravel(f))
        return out

    _, f_val, jac = eff.force_and_jacobian(m.context(q, s, h))
    assert np.all(np.isfinite(f_val))
    J = dense_effect_jacobian(m, eff, jac)
    J_fd = fd_jacobian(F, q, 1e-7)
    if name == "gravity":
        assert np.abs(J_fd).max() < 1e-9 and not jac      # constant force: no Jacobian
    else:
        assert np.linalg.norm(J_fd) > 0
        assert rel_err(J, J_fd) < 1e-6


def test_rft_force_matches_paper_formula_for_a_straight_rod():
    """A straight flagellum moving sideways at v feels eta_p * v per length; moving along itself, eta_t * v."""
    sc = load_scene("clamped_flagellum")
    m = RobotModel(sc)
    st = m.initial_state()
    rft = m.effect("rft")
    L = sc.flagellum.length
    for direction, eta in (([0.0, 0.0, 1.0], sc.eta_p), ([1.0, 0.0, 0.0], sc.eta_t)):
        q = st.q.copy()
        v = 1e-3 * np.array(direction)
        x = q[: 3 * m.net.n_nodes].reshape(-1, 3)
        x[m.net.flagella_nodes[0]] += v * 0.01
        F = rft.node_forces(m.context(q, st, 0.01))
        assert np.allclose(F.sum(axis=0), -eta * L * v, rtol=1e-12, atol=0)


def test_full_residual_jacobian_matches_finite_differences():
    """The assembled sparse Jacobian (elastic + all effects, pattern built once) is the residual's derivative."""
    m, s, h, q = newton_point(moving_robot())
    r, data, _ = m.residual_and_jacobian(q, s, h)
    J = m.pattern.matrix(data).toarray()
    J_fd = fd_jacobian(lambda qq: m.residual(qq, s, h), q, 1e-7)
    assert rel_err(J, J_fd) < 1e-6
    assert np.allclose(r, m.residual(q, s, h), rtol=1e-12, atol=1e-15)


def test_scene_builds_only_listed_effects():
    m = RobotModel(load_scene("design1", ["scene.effects=['rft','motor']"]))
    assert m.effect_names == ["rft", "motor"]
    assert not any(e.on_head and e.name != "motor" for e in m.effects)
    assert m.effect("head_drag") is None and m.effect("head_torque") is None and m.effect("inertia") is None


def test_scene_without_head_effects_builds_no_head_objects():
    m = RobotModel(load_scene("clamped_flagellum"))
    assert not any(e.on_head for e in m.effects)
    assert len(m.net.head_nodes) == 0 and m.net.head_edge == -1 and m.net.motor_hinge == -1
    # and the Jacobian pattern holds only what the listed effects and the elastic springs need
    m_full = RobotModel(load_scene("design1"))
    m_bare = RobotModel(load_scene("design1", ["scene.effects=['rft','motor']"]))
    assert m_bare.pattern.nnz <= m_full.pattern.nnz
    assert len(m_bare.pattern.slots) == len(m_full.pattern.slots) - len(
        [b for e in m_full.effects if e.name in ("inertia", "head_drag", "head_torque") for b in e.blocks()])
