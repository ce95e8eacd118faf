"""The accuracy presets deliver the accuracy docs/accuracy.md states, measured against an independent reference:
the steady clamped flagellum from the geometrically exact rod equations (flagbot_sim.reference.rod_bvp).

The case, its reference and its outputs are the accuracy study's own (flagbot_sim.bench.accuracy)."""
import pytest

from flagbot_sim.bench.accuracy import CASES, outputs_of, rod_bvp_reference
from flagbot_sim.physics import Simulation
from flagbot_sim.scene import load_scene

# the study measured 2.05%, 0.78% and 0.38% (largest relative error over Fx, Tx and the tip, vs Richardson)
BOUNDS = {"fast": 0.03, "default": 0.012, "accurate": 0.006}


@pytest.fixture(scope="module")
def reference():
    return rod_bvp_reference("clamped")


def errors(preset, ref):
    scene_name, overrides = CASES["clamped"]
    sim = Simulation(load_scene(scene_name, [*overrides, f"scene.preset='{preset}'"]))
    sim.run(25.0)
    assert sim.summary()["steady"]
    got = outputs_of(sim)
    return max(abs(got[k] - ref[k]) / abs(ref[k]) for k in ref)


def test_presets_meet_their_stated_accuracy_and_are_ordered(reference):
    err = {p: errors(p, reference) for p in BOUNDS}
    for p, bound in BOUNDS.items():
        assert err[p] < bound, (p, err[p])
    assert err["fast"] > err["default"] > err["accurate"]
