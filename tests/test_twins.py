"""The interpreted twins a first run steps with while the background compile runs (physics/warmup.py, jit.py):
the same numbers as the compiled kernels to the last bit, and a switch to the compiled step mid-run changes none."""
import numpy as np
import pytest

from flagbot_sim.physics import Simulation, warmup
from flagbot_sim.physics import jit
from flagbot_sim.physics.jit import interpreted
from flagbot_sim.physics.linsolve import ArrowSolver, flagellum_chains
from flagbot_sim.physics.newton import error_sums, residual_norms
from flagbot_sim.scene import load_scene

from fd import newton_point

BACKGROUND = [g for g in warmup.GROUPS if warmup.GROUPS[g].background]


def same(a, b) -> bool:
    """Equal to the last bit (NaN included)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


@pytest.fixture
def compiled():
    """Every group compiled and loaded (the twins are compared against them), none deferred; the deferral as it
    was afterwards."""
    warmup.ensure_compiled()
    saved = set(warmup.DEFERRED)
    warmup.DEFERRED.clear()
    yield
    warmup.DEFERRED.clear()
    warmup.DEFERRED.update(saved)


@pytest.fixture
def deferred(compiled):
    """The background groups deferred, as in a first run while their compile is under way."""
    warmup.DEFERRED.update(BACKGROUND)
    yield


def test_an_interpreted_twin_calls_no_compiled_code_and_gives_the_same_bits():
    rng = np.random.default_rng(5)
    r, scale, w = rng.standard_normal(300), rng.random(300), rng.random(300)
    q1, q0 = rng.standard_normal(300), rng.standard_normal(300)
    assert same(interpreted(residual_norms)(r, scale), residual_norms(r, scale))
    assert same(interpreted(error_sums)(w, r, q1, q0), error_sums(w, r, q1, q0))
    r[7] = np.nan                                         # the NaN flag of the largest entry
    assert same(interpreted(residual_norms)(r, scale), residual_norms(r, scale))
    twin = interpreted(residual_norms)
    assert twin.__globals__["_norms"] is interpreted(warmup._dispatcher("newton.residual_norms").py_func.__globals__[
        "_norms"])                                        # its callee is a twin too, not the compiled stage
    assert interpreted(residual_norms) is twin            # one twin per function


@pytest.mark.parametrize("scene,overrides", [("design1", ["robot.n_flagella=3"]), ("design2", ["robot.n_flagella=5"])])
def test_the_arrow_solvers_twin_writes_the_same_factors_and_solutions(compiled, scene, overrides):
    sim = Simulation(load_scene(scene, overrides))
    sim.run(0.2)
    m, s, plan, q = newton_point(sim, noise_seed=3)
    ctx = m.context(q, s, plan)
    data, r = m.jacobian(ctx), m.residual(ctx)
    results = []
    for twin in (False, True):
        arrow = ArrowSolver(m.pattern, flagellum_chains(m.net))
        if twin:
            warmup.DEFERRED.add("arrow")
        assert warmup.deferred("arrow") is twin and warmup.loaded("arrow")
        try:
            arrow.factor(data)
            x = arrow.solve(r)
        finally:
            warmup.DEFERRED.discard("arrow")
        results.append((arrow._buf.copy(), arrow._ipiv.copy(), arrow._core_piv.copy(), arrow._Y.copy(), x))
    (buf, ipiv, cpiv, Y, x), (buf2, ipiv2, cpiv2, Y2, x2) = results
    assert same(buf, buf2) and np.array_equal(ipiv, ipiv2) and np.array_equal(cpiv, cpiv2) and same(Y, Y2)
    assert same(x, x2)
    A = m.pattern.matrix(data)
    assert np.abs(A @ x2 - r).max() <= 1e-10 * np.abs(r).max()      # and it is a solution


def _run(T: float, overrides: list[str], swap_at: int | dict | None = None, twins: bool = False):
    """A run of design 1 (n = 3); ``swap_at``: the step after which the deferred groups are swapped in, all at
    once (an int) or each at its own step (a dict group -> step: what swap_in does as the cache gets them)."""
    sim = Simulation(load_scene("design1", ["robot.n_flagella=3", *overrides]))
    if twins:
        sim.stepper._newton = None                        # as constructed while the newton group is deferred
    if isinstance(swap_at, int):
        swap_at = dict.fromkeys(BACKGROUND, swap_at)
    n = 0
    while sim.time < T - 1e-9:
        for g, at in (swap_at or {}).items():
            if n >= at:
                warmup.DEFERRED.discard(g)                # what swap_in does once the cache has it
        n += sim.advance(1 if warmup.DEFERRED else 50, t_stop=T - 1e-9)
    return sim


@pytest.mark.parametrize("overrides", [[], ["time.rtol=1e-3"]], ids=["fixed-dt", "error-control"])
def test_a_run_on_the_twins_and_one_that_switches_mid_run_match_the_compiled_run_bit_for_bit(deferred, monkeypatch,
                                                                                             overrides):
    monkeypatch.setattr(warmup, "swap_in", lambda: False)     # the cache holds them: the test decides when
    asked = set()
    twin_of = jit.interpreted
    monkeypatch.setattr(jit, "interpreted", lambda d: asked.add(d.py_func.__name__) or twin_of(d))
    twins = _run(0.4, overrides, twins=True)
    assert twins.stepper._newton is None
    # every kernel of the deferred groups a step calls from Python was called as its twin
    assert {"_predict_cylindrical", "residual_norms", "error_sums", "robot_pose", "angle3"} <= asked, asked
    warmup.DEFERRED.update(BACKGROUND)
    switched = _run(0.4, overrides, swap_at=15, twins=True)
    assert switched.stepper._newton is not None           # it did switch, and stepped compiled afterwards
    warmup.DEFERRED.update(BACKGROUND)
    # each group as the background compile delivers it: the Python loop on some compiled kernels and some twins
    staggered = _run(0.4, overrides, swap_at={"time_stepping": 5, "arrow": 12, warmup.STEP_GROUP: 20}, twins=True)
    assert staggered.stepper._newton is not None
    warmup.DEFERRED.clear()
    compiled = _run(0.4, overrides)
    assert compiled.stepper._newton is not None
    for sim in (twins, switched, staggered):
        assert sim.steps == compiled.steps
        assert same(sim.state.q, compiled.state.q) and same(sim.state.v, compiled.state.v)
        assert same(sim.state.frames.d1, compiled.state.frames.d1)
        assert same([sim.observer.rate_h, sim.observer.rate_t, sim.observer.speed],
                    [compiled.observer.rate_h, compiled.observer.rate_t, compiled.observer.speed])


def test_swap_in_waits_for_the_cache_and_then_loads_the_groups(deferred, monkeypatch):
    warmup.DEFERRED.intersection_update({"arrow"})
    loads = []                        # at each arrow factorisation of a warm-up: was it deferred in there?
    factor = ArrowSolver.factor
    monkeypatch.setattr(ArrowSolver, "factor", lambda self, data: loads.append(warmup.deferred("arrow")) or
                        factor(self, data))
    monkeypatch.setattr(warmup, "_next_look", 0.0)
    monkeypatch.setattr(warmup, "cache_is_warm", lambda groups=None: False)
    assert warmup.swap_in() is False and warmup.deferred("arrow") and loads == []     # not in the cache yet
    monkeypatch.setattr(warmup, "cache_is_warm", lambda groups=None: True)
    assert warmup.swap_in() is False and warmup.deferred("arrow")          # and it does not look again at once
    monkeypatch.setattr(warmup, "_next_look", 0.0)
    assert warmup.swap_in() is True and not warmup.deferred("arrow")
    assert loads == [False]           # loaded once, its warm-up calling the compiled kernels, not the twins
    assert warmup.swap_in() is False                                       # nothing left to swap


def test_swap_in_loads_each_group_as_the_cache_gets_it_and_the_compiled_step_last(deferred, monkeypatch):
    # a first run's background compile delivers the cheap groups first: the Python loop calls their compiled
    # kernels from then on, and the compiled step (its group calls every other's) comes only once they are all in
    assert set(BACKGROUND) == {"time_stepping", "arrow", warmup.STEP_GROUP}
    cached = set()
    monkeypatch.setattr(warmup, "cache_is_warm", lambda groups=None: set(groups) <= cached)
    sim = Simulation(load_scene("design1"))
    sim.stepper._newton = None                            # as constructed while the groups are deferred

    def look():
        monkeypatch.setattr(warmup, "_next_look", 0.0)
        sim.step()
        return {g for g in BACKGROUND if warmup.deferred(g)}

    assert look() == set(BACKGROUND) and sim.stepper._newton is None          # nothing in the cache yet
    cached.add("time_stepping")
    assert look() == {"arrow", warmup.STEP_GROUP} and sim.stepper._newton is None
    cached.add(warmup.STEP_GROUP)                         # the step's group before one it calls: not yet
    assert look() == {"arrow", warmup.STEP_GROUP} and sim.stepper._newton is None
    cached.add("arrow")
    assert look() == set() and sim.stepper._newton is not None                # all in: the compiled step


def test_every_simulation_built_while_deferred_switches_not_only_the_first(deferred, monkeypatch):
    a = Simulation(load_scene("design1"))
    b = Simulation(load_scene("design1"))
    a.stepper._newton = b.stepper._newton = None          # as constructed while the newton group is deferred
    monkeypatch.setattr(warmup, "_next_look", 0.0)        # the cache is warm: the first look swaps
    a.step()                                              # a's step loads the groups ...
    b.step()                                              # ... and b, built deferred too, switches as well
    assert not warmup.DEFERRED
    assert a.stepper._newton is not None and b.stepper._newton is not None
