"""Real-time pacing (flagbot_sim.pacer), without ROS: a virtual wall clock, and a simulation whose steps take
virtual wall time."""
import math

import pytest

from flagbot_sim.pacer import Pacer


class World:
    """A virtual wall clock and a 'simulation' of fixed steps dt that cost ``cost`` seconds of wall time each."""

    def __init__(self, dt=0.01, cost=0.0):
        self.wall = 0.0
        self.t = 0.0
        self.dt = dt
        self.cost = cost
        self.steps = 0
        self.calls = 0

    def clock(self):
        return self.wall

    def step(self):
        self.t += self.dt
        self.wall += self.cost
        self.steps += 1
        return True

    def steps_(self, n, t_stop):
        """The simulation's batch: up to n steps, none from a time >= t_stop; the steps taken."""
        self.calls += 1
        k = 0
        while k < n and self.t < t_stop:
            self.step()
            k += 1
        return k

    def run(self, pacer, ticks, period=0.02, budget=0.016, dt=None):
        for _ in range(ticks):
            pacer.advance(lambda: self.t, self.steps_, budget, self.dt if dt is None else dt, period)
            self.wall = (math.floor(self.wall / period + 1e-9) + 1) * period      # the next tick


def test_simulated_time_follows_the_requested_real_time_factor():
    for rtf in (0.5, 1.0, 4.0):
        w = World()
        p = Pacer(rtf, 0.0, clock=w.clock)
        w.run(p, 500)                         # 10 s of wall time
        assert w.t == pytest.approx(rtf * w.wall, abs=w.dt + rtf * 0.02)
        assert p.achieved() == pytest.approx(rtf, rel=0.05) and not p.behind


def test_a_slow_simulation_is_behind_spends_only_its_budget_and_owes_no_debt():
    # each step costs 4 ms of wall time and moves 10 ms: 4 steps fit the 16 ms budget of a 20 ms tick
    w = World(cost=0.004)
    p = Pacer(10.0, 0.0, clock=w.clock)
    w.run(p, 200)
    assert p.behind
    assert p.achieved() == pytest.approx(0.04 / 0.02, rel=0.05)     # 4 steps of 10 ms per 20 ms tick
    # re-anchored whenever more than a second of wall time behind: the target never runs away
    assert p.target(w.wall) - w.t <= 10.0 * 1.0 + 0.1


def test_as_fast_as_possible_fills_the_budget_in_a_few_batches():
    """rtf 0: each tick steps for its budget, in batches of half the budget left at the rate seen (one step
    while no rate is known): far fewer calls than steps, never past the budget by more than a step."""
    w = World(cost=0.001)
    p = Pacer(0.0, 0.0, clock=w.clock)
    w.run(p, 10, budget=0.016)
    assert 10 * 15 <= w.steps <= 10 * 16 and not p.behind
    assert w.calls <= 10 * 7 and p.step_rate == pytest.approx(1000.0)


def test_batches_reach_the_target_without_passing_it_and_keep_to_the_budget():
    """rtf > 0 with fixed steps: a tick steps exactly to its target (t + dt / 2 <= target) in batches; a slow
    simulation's tick ends within its budget plus the half of it a batch may use."""
    w = World(dt=0.001, cost=0.0001)
    p = Pacer(2.0, 0.0, clock=w.clock)
    for _ in range(50):
        tick = w.wall
        p.advance(lambda: w.t, w.steps_, 0.016, w.dt, 0.02)
        assert w.t + 0.5 * w.dt > p.target(tick) - 1e-12 and w.t - 0.5 * w.dt <= p.target(tick) + 1e-12
        w.wall = tick + 0.02
    assert w.calls < w.steps / 4
    slow = World(dt=0.01, cost=0.003)
    p = Pacer(20.0, 0.0, clock=slow.clock)
    for _ in range(20):
        tick = slow.wall
        p.advance(lambda: slow.t, slow.steps_, 0.016, slow.dt, 0.02)
        assert slow.wall - tick <= 0.016 + 0.5 * 0.016 + 0.003
        slow.wall = max(slow.wall, tick + 0.02)


def test_error_controlled_steps_go_to_the_target_without_overstepping_it_by_more_than_one():
    """dt None: steps of the simulation's own size while the target is ahead (never cut to the tick)."""
    w = World(dt=0.007)
    p = Pacer(1.0, 0.0, clock=w.clock)
    ts = []
    for _ in range(100):
        p.advance(lambda: w.t, w.steps_, 0.016, None, 0.02)
        ts.append(w.t)
        assert w.t >= p.target(w.wall) and w.t - p.target(w.wall) < w.dt
        w.wall += 0.02
    assert ts == sorted(ts)                  # /clock monotone


def test_anchor_restarts_the_schedule_and_rate_changes_take_effect_at_once():
    w = World()
    p = Pacer(1.0, 0.0, clock=w.clock)
    w.run(p, 50)
    t_before = w.t
    p.set_rtf(3.0, w.t)                      # from now on, 3x: no catching up on the past at the new rate
    w.run(p, 50)
    assert w.t - t_before == pytest.approx(3.0 * 1.0, abs=0.1)


def test_steps_slower_than_a_second_are_behind_at_every_tick_and_the_time_given_up_is_counted():
    """The issue's crawl: each 10 ms step took 1.25 s of wall time. Judged on the tick alone it looked on time at
    every other tick (the re-anchoring set the target back to the present); the achieved rate does not forget."""
    w = World(dt=0.01, cost=1.25)
    p = Pacer(1.0, 0.0, clock=w.clock)
    verdicts = []
    for _ in range(12):
        p.advance(lambda: w.t, w.steps_, 0.016, w.dt, 0.02)
        verdicts.append(p.behind)
        w.wall += 0.02                           # the next tick (already due after a slow step)
    assert all(verdicts[2:]), verdicts
    assert p.achieved() == pytest.approx(0.01 / 1.25, rel=0.6)
    # the schedule's whole debt is accounted for: given up at the re-anchorings, or still owed since the last one
    owed = p.target(w.wall) - w.t
    assert p.given_up + owed == pytest.approx(w.wall - w.t, abs=1e-9) and p.given_up > 0.8 * (w.wall - w.t)


def test_a_run_slightly_too_slow_is_behind_although_no_tick_misses_by_two_steps():
    """85% of the requested rate: each tick ends short by less than two steps, but it never catches up."""
    w = World(dt=0.001, cost=0.0)
    p = Pacer(1.0, 0.0, clock=w.clock)
    late = []
    for k in range(300):                         # 6 s of 20 ms ticks, 17 of the 20 steps each could need
        for _ in range(17):
            w.step()
        p.advance(lambda: w.t, lambda n, t_stop: 0, 0.0, w.dt, 0.02)    # no budget: it steps no further itself
        w.wall += 0.02
        late.append(p.behind)
    assert p.achieved() == pytest.approx(0.85, rel=0.02)
    assert all(late[100:])
    p.restart_window()                           # a pause / reset / new rate: the verdict starts afresh
    assert not p.behind and p.achieved() is None
