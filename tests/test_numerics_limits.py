"""Numerics that cannot be met are refused at scene validation (the CLI and sim_node alike, naming the key), and
what slows a run is visible: `flagbot run` warns once when steps are being cut repeatedly."""
import json
import re

import pytest
from cli_helpers import flagbot

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.medium import force_scale
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.scene import MIN_NEWTON_ITERATIONS, NumericsSection, SceneError, load_scene

DEFAULT_TOL = NumericsSection.force_tol


def floor_of(name, overrides=()):
    """The model's Newton floor of a scene, relative to EI/L^2 (what the solver stops at whatever is asked)."""
    sc = load_scene(name, list(overrides))
    model = RobotModel(sc)
    return model.force_floor / force_scale(sc)


@pytest.mark.parametrize("tol", ["1e-300", "1e-12", "1e-8"])
def test_a_force_tolerance_below_the_round_off_floor_is_refused_naming_the_key_and_the_floor(tol):
    floor = floor_of("design1")
    assert floor > 1e-8            # design 1's stiff plate: the floor is above every value tried here
    with pytest.raises(SceneError) as err:
        load_scene("design1", [f"numerics.force_tol={tol}"])
    text = str(err.value)
    assert text.startswith(f"numerics.force_tol = {float(tol):g} cannot be met")
    assert f"{floor:.3g}" in text and "numerics.rigid_factor = 1000" in text
    # the bound it quotes is accepted (rounded up, never below the floor), and the model then uses it as is
    bound = float(re.search(r"use >= (\S+)", text).group(1))
    sc = load_scene("design1", [f"numerics.force_tol={bound}"])
    assert bound >= floor and RobotModel(sc).force_tol == pytest.approx(bound * force_scale(sc), rel=1e-12)


def test_scene_and_model_draw_the_line_at_the_same_floor():
    """Just above the model's floor is accepted, just below refused: one formula serves both."""
    tried = 0
    for name, over in [("design2", ["numerics.rigid_factor=10"]), ("clamped_flagellum", ["numerics.rigid_factor=3"]),
                       ("design1", ["numerics.rigid_factor=10"]),
                       ("design1", ["flagellum.edge_length=1e-4", "numerics.rigid_factor=1"])]:
        floor = floor_of(name, over)
        assert floor < DEFAULT_TOL           # else the default is always accepted: nothing to draw a line at
        tried += 1
        load_scene(name, [*over, f"numerics.force_tol={floor * (1 + 1e-9)!r}"])
        with pytest.raises(SceneError, match="numerics.force_tol"):
            load_scene(name, [*over, f"numerics.force_tol={floor * (1 - 1e-9)!r}"])
    assert tried == 4


def test_the_default_tolerance_is_accepted_on_a_robot_whose_floor_is_coarser():
    """Recordings and written-out scenes carry the default: it stays readable, and it means the floor there."""
    over = ["numerics.rigid_factor=1e5"]
    assert floor_of("design1", over) > DEFAULT_TOL
    for extra in ([], [f"numerics.force_tol={DEFAULT_TOL}"]):
        sc = load_scene("design1", over + extra)
        model = RobotModel(sc)
        assert model.force_tol == model.force_floor > DEFAULT_TOL * force_scale(sc)


@pytest.mark.parametrize("cap", list(range(1, MIN_NEWTON_ITERATIONS)))
def test_an_iteration_cap_too_small_to_converge_a_step_is_refused_with_the_reason(cap):
    with pytest.raises(SceneError) as err:
        load_scene("design1", [f"numerics.max_iterations={cap}"])
    text = str(err.value)
    assert text.startswith(f"numerics.max_iterations = {cap} is out of range: must be >= {MIN_NEWTON_ITERATIONS}")
    assert "cut into sub-steps" in text


def test_the_smallest_accepted_iteration_cap_converges_the_built_in_scenes_without_crawling():
    """At MIN_NEWTON_ITERATIONS every built-in scene steps 1 s from rest with at most a few steps cut, never
    'repeatedly' (the cap 1 of the issue cut 2150 times in 20 steps)."""
    for name in ("design1", "design2", "clamped_flagellum"):
        sim = Simulation(load_scene(name, [f"numerics.max_iterations={MIN_NEWTON_ITERATIONS}"]))
        while sim.time < 1.0 - 1e-9:
            sim.step()
            assert not sim.cutting, (name, sim.cutting_report())
        assert sim.reductions <= 0.1 * sim.steps, (name, sim.reductions)


def test_cli_and_sim_node_refuse_alike():
    p = flagbot("run", "design1", "--set", "numerics.force_tol=1e-300", "--duration", "0.1")
    assert p.returncode == 2 and p.stdout == ""
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: numerics.force_tol = 1e-300 cannot be met")
    from flagbot_sim.device import build_simulation
    with pytest.raises(SceneError) as err:
        build_simulation("design1", 0, ["numerics.force_tol=1e-300"])
    assert f"error: {err.value}" == lines[0]
    with pytest.raises(SceneError, match=r"^numerics.max_iterations = 1 is out of range"):
        build_simulation("design1", 0, ["numerics.max_iterations=1"])


# a soft robot at ten times the paper's step: Newton needs more than 4 iterations at the first steps from rest
CUT = ["--set", "flagellum.youngs_modulus=1e4", "--set", "time.dt=0.1", "--set", "numerics.max_iterations=4"]


def test_run_warns_once_when_steps_are_cut_repeatedly_with_the_numbers():
    p = flagbot("run", "design1", *CUT, "--duration", "3", "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    warned = [ln for ln in p.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warned) == 1 and out["warnings"] == [warned[0][len("warning: "):]]
    m = re.search(r"(\d+) dt reductions in the last (\d+) steps \((\d+) in (\d+) steps so far\)", warned[0])
    assert m, warned[0]
    cuts, window, total, steps = map(int, m.groups())
    assert cuts >= 20 and cuts == total <= out["dt_reductions"] and window == steps <= out["steps"]
    assert "numerics.max_iterations = 4" in warned[0]
    # the text summary says it too
    q = flagbot("run", "design1", *CUT, "--duration", "3", "--quiet")
    assert q.returncode == 0 and "WARNING: steps are being cut repeatedly" in q.stdout


def test_a_run_with_the_default_numerics_does_not_warn():
    p = flagbot("run", "design1", "--duration", "1", "--json")
    assert p.returncode == 0, p.stderr
    assert "warnings" not in json.loads(p.stdout) and "warning:" not in p.stderr
