"""Every effect's Jacobian agrees with finite differences, and scenes build exactly the effects they list."""
import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.medium import rft_coefficients
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.scene import load_scene

from fd import fd_jacobian, newton_point, rel_err

ALL_FREE = "['inertia','rft','head_drag','head_torque','motor','gravity']"


def effect_force(model, eff, ctx):
    """The effect's generalised force F (the residual gets -F)."""
    r = np.zeros(model.ndof)
    eff.add_force(ctx, r)
    return -r


def dense_effect_jacobian(model, eff, ctx):
    """dF/dq of one effect, as the effect writes it into the model's CSC pattern (the residual gets -dF/dq)."""
    J = np.zeros(model.pattern.nnz)
    eff.add_jacobian(ctx, J)
    return -model.pattern.matrix(J).toarray()


def moving_robot(scene="design1", extra=()):
    sc = load_scene(scene, ["robot.n_flagella=2", "flagellum.length=0.03", f"scene.effects={ALL_FREE}", *extra])
    sim = Simulation(sc)
    for _ in range(15):
        sim.step()
    return sim


WITH_YIELD = f"scene.effects={ALL_FREE[:-1]},'granular_yield']"
WITH_SPIN = f"scene.effects={ALL_FREE[:-1]},'spin_drag']"
# the granular yield is nonlinear in the head velocity on the scale max(|v|, v_eps): the noisy point's head nodes
# move at ~1e-3 m/s, so a step of 1e-9 m (1e-7 m/s) resolves it; at the default v_eps = 1e-7 m/s the law is
# saturated (Coulomb, |F| = F_y), with v_eps = 1e-3 m/s it is in its regularised range
EFFECT_CASES = [("inertia", (), 1e-7), ("rft", (), 1e-7), ("head_drag", (), 1e-7), ("head_torque", (), 1e-7),
                ("gravity", (), 1e-7), ("granular_yield", (WITH_YIELD,), 1e-9),
                ("granular_yield", (WITH_YIELD, "medium.yield_speed=1e-3"), 1e-9),
                ("spin_drag", (WITH_SPIN,), 1e-7), ("spin_drag", (WITH_SPIN, "medium.spin_drag=granular"), 1e-7)]


@pytest.mark.parametrize("name,extra,h", EFFECT_CASES, ids=[f"{c[0]}{'-' + c[1][-1] if len(c[1]) > 1 else ''}"
                                                           for c in EFFECT_CASES])
def test_effect_jacobian_matches_finite_differences(name, extra, h):
    m, s, plan, q = newton_point(moving_robot(extra=extra), noise_seed=2)
    eff = m.effect(name)

    def F(qq):
        return effect_force(m, eff, m.context(qq, s, plan))

    ctx = m.context(q, s, plan)
    assert np.all(np.isfinite(F(q))) and np.linalg.norm(F(q)) > 0
    J = dense_effect_jacobian(m, eff, ctx)
    J_fd = fd_jacobian(F, q, h)
    if name == "gravity":
        assert np.abs(J_fd).max() < 1e-9 and not eff.blocks() and not J.any()   # constant force: no Jacobian
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
    x = st.q[: 3 * m.net.n_nodes].reshape(-1, 3)
    eta_t, eta_p = rft_coefficients(sc)
    for direction, eta in (([0.0, 0.0, 1.0], eta_p), ([1.0, 0.0, 0.0], eta_t)):
        v = 1e-3 * np.array(direction)
        vq = np.zeros(m.ndof)
        vq[: 3 * m.net.n_nodes].reshape(-1, 3)[m.net.flagella_nodes[0]] = v
        F = rft.node_forces(x, vq)
        assert np.allclose(F.sum(axis=0), -eta * L * v, rtol=1e-12, atol=0)


def test_full_residual_jacobian_matches_finite_differences():
    """The assembled sparse Jacobian (elastic + all effects, pattern built once) is the residual's derivative."""
    m, s, plan, q = newton_point(moving_robot())
    ctx = m.context(q, s, plan)
    r, data = m.residual_and_jacobian(ctx)
    J = m.pattern.matrix(data).toarray()
    J_fd = fd_jacobian(lambda qq: m.residual(m.context(qq, s, plan)), q, 1e-7)
    assert rel_err(J, J_fd) < 1e-6
    assert np.allclose(r, m.residual(ctx), rtol=1e-12, atol=1e-15)
    assert np.array_equal(data, m.jacobian(ctx))


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


def test_one_registry_names_every_effect():
    """The scene's allowed effect names are the physics registry's, each class carries its own name, and an
    effect is built by its class's from_scene for exactly the names a scene lists."""
    from flagbot_sim import scene as scene_mod
    from flagbot_sim.physics.effects import EFFECT_TYPES, Effect
    assert list(scene_mod.EFFECTS) == list(EFFECT_TYPES)
    assert all(cls.name == name and cls.description and issubclass(cls, Effect) for name, cls in EFFECT_TYPES.items())
    assert set(scene_mod.HEAD_EFFECTS) == {n for n, c in EFFECT_TYPES.items() if c.on_head}
    m = RobotModel(load_scene("design1", [f"scene.effects={ALL_FREE}"]))
    assert [type(e) for e in m.effects] == [EFFECT_TYPES[n] for n in eval(ALL_FREE)]
    with pytest.raises(scene_mod.SceneError, match="unknown effect 'viscous'.*valid effects: inertia, rft"):
        load_scene("design1", ["scene.effects=['rft', 'viscous']"])


def test_an_effect_must_fill_the_blocks_it_declared():
    """No silent zero Jacobian blocks: slots for fewer (or more) blocks than declared is an error."""
    m = RobotModel(load_scene("design1"))
    rft = m.effect("rft")
    with pytest.raises(ValueError, match="declared 3 Jacobian blocks, got 2"):
        rft.bind(rft.slots[:2])


@pytest.mark.parametrize("model", ["viscous", "granular"])
def test_spin_drag_resists_a_spinning_flagellum_with_its_stated_coefficient(model):
    """The clamped flagellum at 0.5 rpm is nearly straight along the axis, so every edge spins at omega about its
    own tangent: the spin drag adds -c L omega to the medium's axial torque (c = 4 pi mu r0^2, or the granular
    analogue spin_traction eta_t r0^2) and leaves the axial force alone."""
    from flagbot_sim.physics.medium import rft_coefficients, spin_drag_coefficient
    from flagbot_sim.physics.steady import SteadySolver, summary
    out = {}
    for effects in ("['inertia','rft','clamp']", "['inertia','rft','clamp','spin_drag']"):
        sc = load_scene("clamped_flagellum", ["motor.omega_rpm=0.5", f"scene.effects={effects}",
                                              f"medium.spin_drag={model}", "medium.spin_traction=2.0"])
        m = RobotModel(sc)
        out[effects] = summary(m, SteadySolver(m).solve(sc.omega_T))
    plain, spin = out.values()
    r0, mu = sc.flagellum.radius, sc.medium.mu
    eta_t = rft_coefficients(sc)[0]
    c = 4 * np.pi * mu * r0 ** 2 if model == "viscous" else 2.0 * eta_t * r0 ** 2
    assert spin_drag_coefficient(sc) == pytest.approx(c, rel=1e-14)
    # by default, the medium's own: the granular analogue in the paper's medium, Stokes' in a viscous one
    for model, expected in (("granular_rft", eta_t * r0 ** 2), ("viscous", 4 * np.pi * mu * r0 ** 2)):
        assert spin_drag_coefficient(sc.with_overrides({"medium.spin_drag": "medium", "medium.model": model,
                                                        "medium.spin_traction": 1.0})) == pytest.approx(
            expected if model == "viscous" else
            rft_coefficients(sc.with_overrides({"medium.model": model}))[0] * r0 ** 2, rel=1e-14)
    assert spin["Tx"] - plain["Tx"] == pytest.approx(-c * sc.flagellum.length * sc.omega_T, rel=1e-3)
    assert spin["Fx"] == pytest.approx(plain["Fx"], rel=1e-3)
