"""``flagbot bench steady`` compares the steady solver with time stepping to the same accuracy, as cheaply as time
stepping gets there: the step search must find the coarsest accurate step, not stop at the first it is given (the
old default tried only 2e-3 and 1e-3 s and credited the steady solver with up to 5x too much)."""
import math

import pytest

from flagbot_sim.bench.stepsearch import MAX_DOUBLINGS, MAX_HALVINGS, REFINEMENTS, fastest, largest_step, within


def second_order(c: float, cap: float = math.inf):
    """A fake time-stepped run whose error is c dt^2 (BDF2's order), and that never settles above ``cap``."""
    calls = []

    def trial(dt):
        calls.append(dt)
        return {"dt": dt, "error": c * dt * dt, "steady": dt <= cap, "wall": 1.0 / dt}
    return trial, calls


@pytest.mark.parametrize("c", [1e-2, 1.0, 1e2, 1e4, 1e6])
def test_the_search_ends_at_the_coarsest_accurate_step_within_its_refinement(c):
    accuracy, dt0 = 1e-4, 1e-2
    trial, calls = second_order(c)
    tried = largest_step(trial, dt0, accuracy)
    ok = [r["dt"] for r in tried if within(r, accuracy)]
    best = math.sqrt(accuracy / c)                  # the exact largest step within the accuracy
    if best >= dt0 * 2 ** MAX_DOUBLINGS:            # accurate beyond the search's reach: it went all the way up
        assert max(ok) == dt0 * 2 ** MAX_DOUBLINGS
        return
    if best < dt0 / 2 ** MAX_HALVINGS:             # below its reach: every halving tried, none claimed accurate
        assert not ok and len(calls) == 1 + MAX_HALVINGS
        return
    assert ok, "some step must be accurate"
    # accurate, and the bracket's bisections leave it within 2^(1/2^REFINEMENTS) of the largest accurate step
    assert max(ok) <= best < 2 ** (1.0 / 2 ** REFINEMENTS) * max(ok) * (1 + 1e-12)
    assert calls[0] == dt0                          # the scene's own step is always tried


def test_a_step_that_never_settles_is_not_accurate():
    trial, _ = second_order(1e-6, cap=0.02)          # accurate everywhere, but no steady state above 0.02 s
    tried = largest_step(trial, 1e-2, 1e-4, refinements=0)
    assert max(r["dt"] for r in tried if within(r, 1e-4)) == 0.02
    tried = largest_step(trial, 1e-2, 1e-4)         # bisected between 0.02 (settles) and 0.04 (never does)
    assert 0.02 * 2 ** -0.25 < 0.02 <= max(r["dt"] for r in tried if within(r, 1e-4)) < 0.04


def test_a_failed_run_counts_as_not_accurate():
    r = {"dt": 0.1, "error": math.inf, "steady": False, "wall": math.nan}
    assert not within(r, 1e-4)
    assert within({"error": 1e-4, "steady": True}, 1e-4)
    assert not within({"error": 2e-4, "steady": True}, 1e-4)


def test_no_step_above_the_turn_limit_is_tried():
    # above max_turn / omega the stepper cuts each step into sub-steps: the step asked for is not the one run
    trial, calls = second_order(1e-2)                # accurate up to 0.1 s
    tried = largest_step(trial, 1e-2, 1e-4, dt_max=0.048)
    assert max(calls) == 0.048
    assert max(r["dt"] for r in tried if within(r, 1e-4)) == 0.048
    trial, calls = second_order(1e-2)
    largest_step(trial, 0.1, 1e-4, dt_max=0.048)     # a scene step above the limit starts at the limit
    assert calls[0] == 0.048 and max(calls) == 0.048


def test_the_comparison_is_with_the_cheapest_accurate_run_not_the_cheapest_run():
    runs = [{"dt": 0.04, "error": 2e-4, "steady": True, "wall": 0.05},      # cheapest, but not accurate
            {"dt": 0.02, "error": 5e-5, "steady": True, "wall": 0.12},
            {"dt": 0.028, "error": 8e-5, "steady": True, "wall": 0.10},
            {"dt": 0.01, "error": 1e-6, "steady": False, "wall": 0.08}]     # never settled
    assert fastest(runs, 1e-4)["dt"] == 0.028
    assert fastest(runs[:1], 1e-4) is None
