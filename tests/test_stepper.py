"""Time stepping: the motor integrates omega_T, failed Newton attempts halve dt, a failure is loud and harmless."""
import math

import numpy as np
import pytest

from flagbot_sim.physics import Simulation, StepFailed
from flagbot_sim.scene import load_scene


def small_robot(*extra):
    return Simulation(load_scene("design2", ["flagellum.length=0.04", *extra]))


def natural_twist(sim) -> float:
    """The motor hinge's natural twist in force at the current state: its rest value plus the drive angle."""
    h = sim.model.effect("motor").twist_hinge
    return sim.model.elastic.tau_bar[h] + sim.state.drive_angle


def test_motor_natural_twist_integrates_a_changing_omega():
    """Paper Eq. SpecifyTheta as an integral: changing omega_T mid-run never makes the natural twist jump."""
    sim = small_robot()
    base = natural_twist(sim)
    expected = 0.0
    for omega in (2.0, -3.0, 7.5):
        sim.set_omega(omega)
        for _ in range(5):
            before = natural_twist(sim)
            sim.step()
            expected += omega * sim.dt
            assert natural_twist(sim) - before == pytest.approx(omega * sim.dt, rel=1e-12)
    assert natural_twist(sim) - base == pytest.approx(expected, rel=1e-12)
    assert sim.state.drive_angle == pytest.approx(expected, rel=1e-12)
    # and the motor torque is the twisting moment of exactly that natural twist
    el, h = sim.model.elastic, sim.model.net.motor_hinge
    _, _, tau = el.hinge_strains(sim.state.q, el.trial_frames(sim.state.q, sim.state.frames))
    assert sim.motor_torque() == pytest.approx(-el.k_twist[h] * (tau[h] - natural_twist(sim)), rel=1e-12)


def test_relative_spin_of_head_and_flagella_follows_the_motor():
    """The motor hinge is stiff: head and flagella turn apart by the commanded angle (up to the hinge's lag)."""
    sim = small_robot()
    sim.run(1.0)
    ob = sim.observer
    assert ob.phi_h + ob.phi_t == pytest.approx(sim.omega_T * sim.time, rel=2e-3)


def test_newton_failure_halves_dt_and_still_covers_the_step():
    sim = small_robot("motor.omega_rpm=250")
    sim.stepper.max_iterations = 2           # below what a scene accepts: a cap that fails Newton on purpose
    stats = sim.step()
    assert stats.reductions >= 1 and stats.substeps >= 2 and stats.dt_min < sim.dt
    assert sim.time == pytest.approx(sim.dt, rel=1e-12)
    assert np.all(np.isfinite(sim.state.q)) and np.all(np.isfinite(sim.state.v))
    assert sum(stats.substep_dts) == pytest.approx(sim.dt, rel=1e-12)
    # the same sub-steps taken one by one by a solver allowed enough iterations give the same state
    ref = small_robot("motor.omega_rpm=250")
    for h in stats.substep_dts:
        ref.step(h)
    assert np.abs(sim.state.q - ref.state.q).max() < 1e-9


def test_a_step_that_cannot_converge_fails_loudly_and_keeps_the_state():
    sim = small_robot("numerics.min_dt=5e-3", "motor.omega_rpm=2000")
    sim.stepper.max_iterations = 1           # (a scene refuses it: see test_numerics_limits.py)
    base = natural_twist(sim)
    q0 = sim.state.q.copy()
    t0 = sim.time
    with pytest.raises(StepFailed, match="did not converge"):
        sim.step()
    assert sim.time == t0 and np.array_equal(sim.state.q, q0)
    assert sim.state.drive_angle == 0.0 and natural_twist(sim) == base      # no half-applied twist
    # and the simulation carries on once the command is reasonable again
    sim.stepper.max_iterations = 25
    sim.set_omega(1.0)
    sim.step()
    assert sim.time == pytest.approx(sim.dt) and np.all(np.isfinite(sim.state.q))


def test_non_finite_commands_are_refused():
    sim = small_robot()
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match="finite"):
            sim.set_omega(bad)


def test_reset_restores_the_initial_state():
    sim = small_robot()
    sim.run(0.3)
    sim.reset()
    assert sim.time == 0.0 and np.array_equal(sim.state.q, sim.initial.q)
    assert sim.state.drive_angle == 0.0 and sim.omega_T == sim.scene.omega_T
    a = sim.summary()
    sim2 = small_robot()
    sim.run(0.2)
    sim2.run(0.2)
    assert np.array_equal(sim.state.q, sim2.state.q)      # deterministic replay after reset
    assert a["steps"] == 0


@pytest.mark.parametrize("rigid_factor", [1e2, 1e3, 1e5])
def test_rigid_parts_stay_rigid_without_slowing_newton(rigid_factor):
    """Stiffer head/plate: smaller strain in the rigid parts, and Newton's iteration count stays bounded.

    (At 1e5, a hundred thousand times the flagellum's stiffness, the violent 0 -> 150 rpm start from rest
    costs a few counted dt halvings in its first 0.1 s; the default is 1e3.)"""
    sim = small_robot(f"numerics.rigid_factor={rigid_factor}", "motor.omega_rpm=150")
    sim.run(1.0)
    assert sim.newton_iterations / sim.steps <= 2.5
    assert sim.reductions <= (0 if rigid_factor <= 1e3 else 10)
    el, net = sim.model.elastic, sim.model.net
    fr = el.trial_frames(sim.state.q, sim.state.frames)
    stretch = np.abs(el.stretch_strain(fr))
    flex = stretch[net.edge_elastic].max()
    assert stretch[~net.edge_elastic].max() < 10.0 / rigid_factor * max(flex, 1e-9) + 1e-12


def test_the_drive_command_is_an_argument_of_the_step_not_state_of_the_motor():
    """Two steps from one state with two commands: each turns the drive by its own omega h, and the motor effect
    holds no command (nothing a step could leave behind for the next one)."""
    sim = small_robot()
    sim.run(0.05)
    state, st, h = sim.state, sim.stepper, sim.dt
    a, _ = st.step(state, h, 3.0)
    b, _ = st.step(state, h, -5.0)
    assert a.drive_angle == pytest.approx(state.drive_angle + 3.0 * h, rel=0, abs=1e-12)
    assert b.drive_angle == pytest.approx(state.drive_angle - 5.0 * h, rel=0, abs=1e-12)
    assert not hasattr(sim.model.driver, "omega")


@pytest.mark.parametrize("scene,extra", [
    ("design1", ["robot.n_flagella=3", "motor.omega_rpm=150"]),
    ("clamped_flagellum", []),
    ("design1", ["scene.preset='fast'"]),          # error-controlled steps, rejections
    ("design2", ["scene.effects=['inertia','rft','head_drag','head_torque','motor','granular_yield','gravity']"]),
])
def test_the_compiled_newton_solve_gives_the_python_loops_numbers_to_the_last_bit(scene, extra):
    """The compiled solve of a step (physics/newton.py) and the stepper's Python loop take the same decisions
    with the same arithmetic: the same states bit for bit, the same counts."""
    runs = []
    for compiled in (True, False):
        sim = Simulation(load_scene(scene, extra))
        assert (sim.stepper._newton is not None) is True
        if not compiled:
            sim.stepper._newton = None
        sim.run(1.0)
        runs.append((sim.state, sim.newton_iterations, sim.reductions, sim.steps))
    (a, *na), (b, *nb) = runs
    assert na == nb
    for x, y in ((a.q, b.q), (a.v, b.v), (a.frames.d1, b.frames.d1), (a.frames.ref_twist, b.frames.ref_twist)):
        assert np.array_equal(x, y)


def _same(x, y) -> bool:
    """Equal to the last bit, NaN equal to NaN."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    return x.shape == y.shape and bool(np.all((x == y) | (np.isnan(x) & np.isnan(y))))


@pytest.mark.parametrize("scene,extra", [
    ("design1", ["robot.n_flagella=3", "motor.omega_rpm=150"]),
    ("design1", ["robot.n_flagella=2"]),
    ("design2", ["robot.n_flagella=3"]),
    ("design2", ["robot.n_flagella=2", "time.integrator='implicit_euler'"]),
    ("design1", ["robot.n_flagella=3", "scene.preset='fast'"]),                  # error control, rejections
    ("design2", ["robot.n_flagella=2", "scene.preset='fast'"]),
    ("design1", ["robot.n_flagella=2", "time.rtol=1e-3", "time.integrator='implicit_euler'"]),
    # fixed steps whose Newton fails at dt: the compiled steps hand the step to the Python code, which halves it
    ("design2", ["scene.effects=['inertia','rft','head_drag','head_torque','motor','granular_yield','gravity']"]),
])
def test_the_compiled_steps_give_the_step_by_step_numbers_to_the_last_bit(scene, extra):
    """Simulation.run takes its steps in batches in one compiled call each (newton._advance: prediction, solve,
    error estimate and step size, the observer's spin angles, rates and history); step by step the stepper's
    Python code does the same. Both: the same states, observations, counts and steady-state rule, bit for bit
    (a short steady window, so the rule samples between batches too; and the command changed once)."""
    runs = []
    for batched in (True, False):
        sim = Simulation(load_scene(scene, extra), steady_window=0.2)
        assert sim.stepper.can_advance(sim.dt, sim.omega_T)
        for omega in (sim.omega_T, 0.5 * sim.omega_T):
            sim.set_omega(omega)
            if batched:
                sim.run(0.6)
            elif sim.adaptive:
                t_end = sim.time + 0.6
                while sim.time < t_end - 1e-12 * max(1.0, abs(t_end)):
                    sim.step(t_end=t_end)
            else:
                for _ in range(int(round(0.6 / sim.dt))):
                    sim.step()
        runs.append(sim)
    a, b = runs
    assert (a.steps, a.newton_iterations, a.reductions) == (b.steps, b.newton_iterations, b.reductions)
    assert a.steps > 20
    assert a.state.t == b.state.t and a.state.h == b.state.h and a.state.h_next == b.state.h_next
    for sa, sb in ((a.state, b.state), (a._prev_state, b._prev_state)):
        for x, y in ((sa.q, sb.q), (sa.v, sb.v), (sa.q_prev, sb.q_prev), (sa.frames.t, sb.frames.t),
                     (sa.frames.d1, sb.frames.d1), (sa.frames.d2, sb.frames.d2),
                     (sa.frames.ref_twist, sb.frames.ref_twist)):
            assert _same(x, y)
    assert _same(a.snapshot().values(), b.snapshot().values())
    assert _same(a.observer.history.rows(), b.observer.history.rows())
    assert _same([e for _, e in a._velocity_errors], [e for _, e in b._velocity_errors])
    assert _same(a.steady_detector.tails, b.steady_detector.tails) and a.steady == b.steady
    assert len(a.steady_detector.samples) >= 3
    la, lb = a.last_stats, b.last_stats
    assert (la.newton_iterations, la.residual, la.dt_min, la.reductions, la.rejections) == \
        (lb.newton_iterations, lb.residual, lb.dt_min, lb.reductions, lb.rejections)
    sa, sb = a.summary(), b.summary()
    for k in ("omega_h", "omega_t", "v", "steady_change", "time", "motor_torque"):
        assert _same(sa[k], sb[k]), k


def test_the_compiled_steps_call_back_as_often_as_the_steps_did():
    """run(every=10) calls its callback after the first step, every 10th and the last, as a callback that acts
    on every 10th step (the CLI's progress) would; batches end there."""
    sim = small_robot()
    seen = []
    sim.run(0.35, callback=lambda s: seen.append(s.steps), every=10)
    assert seen == [1, 11, 21, 31, 35]
    seen.clear()
    sim.run(0.05, callback=lambda s: seen.append(s.steps))
    assert seen == [36, 37, 38, 39, 40]


@pytest.mark.parametrize("extra", [[], ["time.rtol=1e-3"]])
def test_a_failing_step_in_a_batch_fails_as_it_does_step_by_step(extra):
    """A step that cannot converge in the middle of a batch (fixed: the Python stepper halves it down to
    min_dt; error-controlled: the compiled steps cut it below min_dt) raises the same StepFailed as step by step
    and keeps the same last good state, the steps before it counted."""
    got = []
    for batched in (True, False):
        sim = small_robot("numerics.min_dt=1e-4", *extra)
        sim.run(0.2)
        sim.stepper.max_iterations = 1           # (a scene refuses it: see test_numerics_limits.py)
        sim.set_omega(40.0)                      # (below the turn limit: the fixed steps are batched)
        with pytest.raises(StepFailed) as info:
            if batched:
                sim.run(1.0)
            else:
                while True:
                    sim.step(t_end=sim.time + 1.0 if sim.adaptive else math.inf)
        got.append((str(info.value), sim.steps, sim.state.t, sim.state.q.copy(), sim.snapshot().values()))
    (ma, na, ta, qa, sa), (mb, nb, tb, qb, sb) = got
    assert "did not converge" in ma
    assert (ma, na, ta) == (mb, nb, tb) and np.array_equal(qa, qb) and np.array_equal(sa, sb)


def _steps_with_choice(sim, n: int) -> tuple[list[float], list[int]]:
    """Step by step: Newton's start after each step (1: first-order continuation) and its iterations."""
    order, its = [], []
    for _ in range(n):
        sim.step()
        order.append(sim.stepper._kept[2])
        its.append(sim.last_stats.newton_iterations)
    return order, its


def test_newton_starts_from_the_first_order_continuation_once_it_predicts_better(monkeypatch):
    """In a steady rotation the motion about the axis is first order exactly and the second differences of the
    states are Newton's tolerance, which the second-order continuation amplifies: the stepper starts from the
    first-order continuation there (this small robot: already early in its spin-up, where that start stays
    near enough), and needs fewer corrections for the same motion (solver tolerance apart)."""
    sim = small_robot()
    order, its = _steps_with_choice(sim, 500)
    assert order[2] == 0.0                               # the first step with both: second order
    assert np.mean(order[-200:]) > 0.9                   # the steady rotation: first order
    with_choice = np.mean(its[-200:])
    from flagbot_sim.physics.stepper import Stepper
    monkeypatch.setattr(Stepper, "_choose_order", lambda self, both, q: None)
    ref = small_robot()
    order_ref, its_ref = _steps_with_choice(ref, 500)
    assert not any(order_ref)
    assert with_choice < 0.7 * np.mean(its_ref[-200:]), (with_choice, np.mean(its_ref[-200:]))
    # the same motion: the two differ by Newton's tolerance, not by the predictor
    s, r = sim.summary(), ref.summary()
    for k in ("omega_h", "omega_t", "v"):
        assert s[k] == pytest.approx(r[k], rel=1e-7, abs=1e-12), k
    assert np.max(np.abs(sim.state.q - ref.state.q)[: 3 * sim.model.net.n_nodes]) < 1e-8


def test_the_compiled_steps_choose_newtons_start_as_the_stepper_does_to_the_last_bit():
    """With error control the start switches both ways (a command step is a transient); the compiled steps
    (newton._choose_order) take the same starts as the stepper's Python code: the same states to the last bit."""
    runs = []
    for batched in (True, False):
        sim = small_robot("time.rtol=1e-3")
        assert sim.stepper.can_advance(sim.dt, sim.omega_T)      # the compiled steps, not the Python code twice
        orders = []
        for omega in (sim.omega_T, 0.5 * sim.omega_T, -sim.omega_T):
            sim.set_omega(omega)
            t_end = sim.time + 1.5
            if batched:
                sim.run(1.5)
            else:
                while sim.time < t_end - 1e-12 * max(1.0, abs(t_end)):
                    sim.step(t_end=t_end)
                    orders.append(sim.stepper._kept[2])
        runs.append((sim, orders))
    (a, _), (b, orders) = runs
    switches = np.diff(orders)
    assert (switches > 0).sum() >= 2 and (switches < 0).sum() >= 2, switches
    assert (a.steps, a.newton_iterations, a.reductions) == (b.steps, b.newton_iterations, b.reductions)
    assert a.stepper._kept[2] == b.stepper._kept[2]
    for x, y in ((a.state.q, b.state.q), (a.state.v, b.state.v), (a.state.q_prev, b.state.q_prev)):
        assert _same(x, y)
    assert _same(a.observer.history.rows(), b.observer.history.rows())


def test_both_continuations_are_exact_for_a_steady_rotation_and_the_second_order_one_amplifies_noise():
    """The robot turning rigidly about its axis at omega and swimming along it: both continuations give the next
    state to round-off. Noise of size eps on the three states (Newton's tolerance) reaches the second-order
    continuation with weights (3, -3, 1) and the first-order one with (2, -1): sqrt(19 / 5) ~ 1.95 times
    larger in RMS."""
    from flagbot_sim.physics.model import State
    from flagbot_sim.physics.stepper import axis_nodes, continuations
    sim = small_robot()
    sim.run(0.3)                                    # a bent robot, off the axis everywhere
    net = sim.model.net
    N = net.n_nodes
    x0 = sim.state.q[: 3 * N].reshape(N, 3).copy()
    i0, i1, i2 = axis_nodes(net)
    axis = x0[i2] - x0[i0]
    axis /= np.linalg.norm(axis)
    centre = x0[i1].copy()
    omega, speed, h = 3.0, 2e-3, 0.01

    def at(t):
        """q at time t: x0 turned by omega t about the axis through the centre, moved by speed t along it."""
        a, K = omega * t, np.cross(np.eye(3), axis)            # K: the cross-product matrix of the axis
        R = np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K
        q = sim.state.q.copy()
        q[: 3 * N] = ((x0 - centre) @ R.T + centre + speed * t * axis).ravel()
        q[3 * N:] += 0.7 * t                                   # twist angles at a steady rate
        return q

    def state(qs, h1=h, h2=h):
        return State(0.0, qs[0], np.zeros_like(qs[0]), None, 0.0, h1, h2, qs[1], np.zeros_like(qs[0]), qs[2])

    for step, h1, h2 in ((h, h, h), (0.013, 0.007, 0.011), (0.004, 0.011, 0.006)):   # unequal steps too
        q2, q1 = continuations(state([at(0.0), at(-h1), at(-h1 - h2)], h1, h2), step, (i0, i1, i2), N)
        truth = at(step)
        scale = np.abs(truth).max()
        assert np.abs(q2 - truth).max() < 1e-12 * scale and np.abs(q1 - truth).max() < 1e-12 * scale
    truth = at(h)
    rng = np.random.default_rng(7)
    eps = 1e-9
    e2 = e1 = 0.0
    for _ in range(20):
        noisy = [at(-k * h) + eps * rng.standard_normal(len(truth)) for k in range(3)]
        q2, q1 = continuations(state(noisy), h, (i0, i1, i2), N)
        e2 += np.sum((q2 - truth)[: 3 * N] ** 2)
        e1 += np.sum((q1 - truth)[: 3 * N] ** 2)
    assert math.sqrt(e2 / e1) == pytest.approx(math.sqrt(19 / 5), rel=0.1)


def test_a_step_taken_again_after_a_folded_iterate_starts_from_the_order_it_began_with(monkeypatch):
    """A folded iterate (ZeroDivisionError) inside a batch: Simulation.advance takes that step again in the
    Python code, from the predictor's order the step began with, although an earlier attempt of it (converged,
    rejected by the error control) had changed it: the same state as that step taken by itself."""
    from flagbot_sim.physics.stepper import Stepper
    sims = [small_robot("time.rtol=1e-3") for _ in range(2)]
    for sim in sims:
        sim.run(1.0)
    assert sims[0].stepper._kept[2] == sims[1].stepper._kept[2]

    def folds(self, b, *args, **kwargs):
        b.icfg[8] = 0                                       # no step taken
        b.last[12] = self._kept[2]                          # the order the step began with ...
        self._kept[2] = 1.0 - self._kept[2]                 # ... changed by an earlier attempt, then a fold
        raise ZeroDivisionError

    monkeypatch.setattr(Stepper, "advance", folds)
    assert sims[0].advance(5) == 1
    sims[1].step(t_end=math.inf)
    a, b = sims
    assert a.stepper._kept[2] == b.stepper._kept[2]
    assert _same(a.state.q, b.state.q) and _same(a.state.v, b.state.v) and a.state.t == b.state.t
