"""Scene files: the documented keys exist and mean what they say; bad input is refused with a useful message."""
import math

import pytest

from flagbot_sim.physics import medium
from flagbot_sim.scene import SceneError, load_scene, parse_overrides, scene_from_dict
from flagbot_sim.scene_files import builtin_scenes
from flagbot_sim.units import RPM


def test_builtin_scenes_carry_the_papers_parameters():
    assert {"design1", "design2", "clamped_flagellum"} <= set(builtin_scenes())
    d1, d2 = load_scene("design1"), load_scene("design2")
    assert (d1.flagellum.length, d2.flagellum.length) == (0.111, 0.089)
    assert (d1.head.radius, d2.head.radius) == (0.02, 0.015)
    assert (d1.plate.diameter, d2.plate.diameter) == (0.04, 0.03)
    assert (d1.head.C1, d1.head.C2, d1.medium.mu) == (2.420, 0.039, 6.828)
    assert (d2.head.C1, d2.head.C2, d2.medium.mu) == (28.750, 0.938, 2.125)
    for d in (d1, d2):
        assert d.flagellum.radius == 3.2e-3 and d.flagellum.youngs_modulus == 1.2e6
        assert d.flagellum.edge_length == 4.11e-3 and d.time.dt == 1e-2 and d.robot.n_flagella == 2
        assert d.flagellum.density == 1000.0 and d.flagellum.poisson_ratio == 0.5
    c = load_scene("clamped_flagellum")
    assert c.clamped and c.robot.n_flagella == 1
    assert (c.flagellum.length, c.medium.mu, c.plate.diameter) == (0.111, 6.828, 0.04)


def test_derived_quantities_follow_the_paper():
    sc = load_scene("design1")
    L, r0, mu = 0.111, 3.2e-3, 6.828
    eta_t, eta_p = medium.rft_coefficients(sc)
    EI = medium.bending_stiffness(sc)
    assert eta_t == pytest.approx(2 * math.pi * mu / (math.log(2 * L / r0) - 0.5))
    assert eta_p == pytest.approx(4 * math.pi * mu / (math.log(2 * L / r0) + 0.5))
    assert EI == pytest.approx(math.pi / 4 * 1.2e6 * r0 ** 4)
    assert medium.force_scale(sc) == pytest.approx(EI / L ** 2)
    assert sc.R_d == pytest.approx(0.02)
    assert sc.omega_T == pytest.approx(100 * 2 * math.pi / 60)
    assert medium.head_drag_coefficient(sc) == pytest.approx(2.42 * 6 * math.pi * mu * 0.02)
    assert medium.head_torque_coefficient(sc) == pytest.approx(0.039 * 8 * math.pi * mu * 0.02 ** 3)
    assert medium.normalise_omega(sc, 1.0) == pytest.approx(eta_p * L ** 4 / EI)
    assert medium.normalise_speed(sc, 1.0) == pytest.approx(eta_p * L ** 3 / EI)


def test_overrides_and_units():
    sc = load_scene("design1", ["robot.n_flagella=3", "motor.omega_rpm=150", "flagellum.length=0.2"])
    assert sc.robot.n_flagella == 3 and sc.flagellum.length == 0.2
    assert sc.omega_T == pytest.approx(150 * RPM)
    sc2 = sc.with_overrides({"time.dt": 0.005})
    assert sc2.time.dt == 0.005 and sc2.robot.n_flagella == 3        # earlier overrides survive
    assert parse_overrides(["scene.effects=['rft','motor']"]) == {"scene.effects": ["rft", "motor"]}


@pytest.mark.parametrize("override,words", [
    ("flagellum.lenght=0.1", ["flagellum.lenght", "length", "radius"]),
    ("robot.n_flagella=0", ["robot.n_flagella", ">= 1"]),
    ("robot.n_flagella=2.5", ["robot.n_flagella", "integer"]),
    ("flagellum.length=-0.1", ["flagellum.length", ">= 1e-06 m and <= 1000 m"]),
    ("flagellum.radius=0.2", ["flagellum.radius", "flagellum.length"]),
    ("flagellum.edge_length=1.0", ["flagellum.edge_length", "flagellum.length"]),
    ("medium.mu='thick'", ["medium.mu", "number"]),
    ("head.C1=-1", ["head.C1", ">= 0"]),
    ("scene.effects=['rft','wind']", ["wind", "head_drag", "gravity"]),
    ("scene.effects=['rft','rft']", ["twice"]),
    ("nosuch.key=1", ["nosuch", "flagellum"]),
    ("time.dt=inf", ["time.dt", "finite"]),
    ("scene.preset='ludicrous'", ["scene.preset", "default"]),
])
def test_bad_values_are_refused_with_the_key_and_what_is_allowed(override, words):
    with pytest.raises(SceneError) as exc:
        load_scene("design1", [override])
    for w in words:
        assert w in str(exc.value)


def test_a_fast_clamp_is_split_into_steps_of_at_most_max_turn():
    """At half a turn per step the clamped arm's tangent would reverse (its frame transport divides by zero), at a
    whole turn the imposed motion would alias to none: so every step is split until it turns at most
    time.max_turn (a quarter turn at most), whatever omega and dt."""
    from flagbot_sim.physics import Simulation
    for rpm, dt in ((3000, 0.01), (-6000, 0.01), (100, 2.0)):
        sim = Simulation(load_scene("clamped_flagellum", [f"motor.omega_rpm={rpm}", f"time.dt={dt}"]))
        st = sim.step()
        turns = [abs(sim.omega_T) * h for h in st.substep_dts]
        assert max(turns) <= sim.scene.time.max_turn + 1e-12 and sum(st.substep_dts) == pytest.approx(dt)
        assert sim.state.drive_angle == pytest.approx(sim.omega_T * dt)
    with pytest.raises(SceneError, match="time.max_turn"):
        load_scene("clamped_flagellum", ["time.max_turn=2.0"])


def test_clamp_cannot_be_combined_with_head_effects_or_several_flagella():
    with pytest.raises(SceneError, match="head_drag"):
        load_scene("clamped_flagellum", ["scene.effects=['clamp','head_drag']"])
    with pytest.raises(SceneError, match="robot.n_flagella"):
        load_scene("clamped_flagellum", ["robot.n_flagella=2"])


def test_unknown_section_and_file_errors(tmp_path):
    with pytest.raises(SceneError, match="unknown section"):
        scene_from_dict({"flagelum": {"length": 0.1}})
    with pytest.raises(SceneError, match="unknown scene"):
        load_scene("design9")
    bad = tmp_path / "bad.toml"
    bad.write_text("[robot\nn_flagella = 2")
    with pytest.raises(SceneError, match="not valid TOML"):
        load_scene(bad)
    good = tmp_path / "mine.toml"
    good.write_text(load_scene("design2").to_toml())
    mine = load_scene(good)
    assert mine.to_dict() == load_scene("design2").to_dict() and mine.source == str(good)


def test_presets_set_the_discretisation_and_explicit_values_win():
    fast = load_scene("design1", ["scene.preset='fast'"])
    assert (fast.time.integrator, fast.time.rtol, fast.flagellum.edge_length) == ("bdf2", 1e-2, 8.22e-3)
    acc = load_scene("design2", ["scene.preset='accurate'"])
    assert (acc.time.rtol, acc.flagellum.edge_length) == (1e-3, 2.055e-3)
    d = load_scene("design1")
    assert (d.time.integrator, d.time.dt, d.time.rtol, d.flagellum.edge_length) == ("bdf2", 1e-2, 0.0, 4.11e-3)
    paper = load_scene("design1", ["scene.preset='paper'"])
    assert (paper.time.integrator, paper.time.dt, paper.flagellum.edge_length) == ("implicit_euler", 1e-2, 4.11e-3)
    assert load_scene("design1", ["scene.preset='fast'", "time.dt=0.05"]).time.dt == 0.05
