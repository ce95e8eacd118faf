"""How the re-simulation reads a recording's motor joint, on synthetic samples (no ROS, no file): a command that
changes sign or passes through zero is pinned as a switch, a restart shows as a jump no command can make (or is
taken from the recorded restart), and a verdict over part of a recording says PARTIAL."""
import numpy as np
import pytest

from flagbot_sim.runs.resim import (POSITION_TOLERANCE, RATE_TOLERANCE, Restart, Resimulation, command_schedule,
                               first_jump, replay_plan)
from flagbot_sim.scene import load_scene

DT = 0.01                                   # the scenes' step
T = np.round(np.arange(0, 151) * 0.02, 9)   # a sample every second step (publish_rate below the step rate)


def motor_joint(schedule, restarts=()):
    """(angle, rate) at the sample times T of a command stream [(t_switch, omega)] that switches on steps of DT,
    the angle integrated step by step as the simulator does and put back to 0 at each restart time."""
    steps = int(round(T[-1] / DT))
    angle, rate = np.zeros(len(T)), np.zeros(len(T))
    phi, w = 0.0, schedule[0][1]
    for n in range(steps + 1):
        t = n * DT
        k = np.nonzero(np.abs(T - t) < 1e-9)[0]
        for ts, wn in schedule:
            if abs(ts - t) < 1e-9:
                w = wn
        if len(k):
            angle[k[0]], rate[k[0]] = phi, w
        if any(abs(t - r) < 1e-9 for r in restarts):
            phi = 0.0           # after the sample of this stamp: the one kept at a restart is the state before it
        phi += w * DT
    return angle, rate


REVERSALS = [(0.0, 10.0), (1.01, -10.0), (2.03, 10.0)]          # switches between two samples
SQUARE = [(0.0, 8.0), (0.41, 0.0), (0.81, -8.0), (1.21, 0.0), (1.61, 8.0), (2.01, -8.0)]


@pytest.mark.parametrize("schedule", [REVERSALS, SQUARE], ids=["reversals", "square_wave_through_zero"])
def test_a_command_that_changes_sign_is_pinned_as_a_switch_not_taken_for_a_restart(schedule):
    angle, rate = motor_joint(schedule)
    assert np.any(np.diff(angle) < 0)                 # the motor turns back
    got, notes = command_schedule(T, angle, rate, DT)
    assert notes == []
    assert [w for _, w in got] == [w for _, w in schedule]
    # each switch is found at the step where it happened, though it lies between two samples
    assert np.allclose([t for t, _ in got], [t for t, _ in schedule], atol=1e-12, rtol=0)
    assert first_jump(T, angle, bound=50.0) is None


def test_a_reset_is_a_jump_no_command_can_make():
    angle, rate = motor_joint([(0.0, 10.0)], restarts=[1.5])
    k = first_jump(T, angle, bound=50.0)
    # 15 rad back to 0.2 rad in 0.02 s: no command up to 50 rad/s turns the motor that far
    assert k is not None and T[k - 1] == pytest.approx(1.5) and angle[k] == pytest.approx(0.2)
    # with commands up to 1e4 rad/s allowed, 200 rad in 0.02 s would be possible: a jump is not a proof then
    assert first_jump(T, angle, bound=1e4) is None


def test_a_command_changed_and_changed_back_between_two_samples_is_noted():
    angle, rate = motor_joint([(0.0, 10.0), (1.01, -10.0), (1.02, 10.0)])
    rate[np.abs(T - 1.02) < 1e-9] = 10.0          # the samples never show -10
    _, notes = command_schedule(T, angle, rate, DT)
    assert len(notes) == 1 and "changed and changed back" in notes[0] and "1.0000 s and 1.0200 s" in notes[0]


def test_the_plan_splits_at_a_recorded_restart_and_starts_it_from_the_initial_state():
    scene = load_scene("design2", ["flagellum.length=0.05"])
    angle, rate = motor_joint([(0.0, 10.0), (2.01, -10.0)], restarts=[1.5])
    motor = ([None] * len(T), T, angle, rate)
    plan = replay_plan(motor, [Restart(1.5, "reset", 10.0, scene.to_toml())], scene, {"max_omega": 50.0}, "x")
    first, second = plan.segments
    assert (first.cause, second.cause) == ("start", "reset") and not plan.uncompared and not plan.notes
    # the sample stamped at the restart is the state before it: it ends the first segment
    assert T[first.index[-1]] == 1.5 and T[second.index[0]] == pytest.approx(1.52)
    assert second.start == 1.5 and second.schedule[0] == (0.0, 10.0)
    assert second.schedule[1][0] == pytest.approx(2.01 - 1.5, abs=1e-12) and second.schedule[1][1] == -10.0
    assert first.compare_until == len(first.index) and second.compare_until == len(second.index)
    assert plan.commands()[-1][0] == pytest.approx(2.01, abs=1e-12)
    # without the record of the restart: the first segment stops at the jump, the rest is not compared
    blind = replay_plan(motor, [], scene, {"max_omega": 50.0}, "x", records_resets=False)
    (only,) = blind.segments
    assert T[only.index[only.compare_until - 1]] == 1.5 and only.compare_until < len(only.index)
    assert len(blind.uncompared) == 1 and "jumps" in blind.uncompared[0] and "no resets topic" in blind.uncompared[0]


def result(**kw):
    base = dict(samples=100, compared_samples=99, recorded_duration=2.0, compared_duration=2.0, complete=True,
                commands=[(0.0, 10.0)], restarts=[], parts=1, max_position_error=0.0, max_omega_h_error=0.0,
                max_omega_t_error=0.0)
    return Resimulation(**{**base, **kw})


def test_the_verdict_covers_the_whole_recording_or_says_partial():
    whole = result()
    assert whole.status == "REPRODUCED" and whole.reproduced and whole.fraction == 1.0
    assert whole.verdict().startswith("verdict: REPRODUCED: compared 2.000 s of the 2.000 s recorded (100.0 %)")
    part = result(compared_samples=20, compared_duration=0.41, complete=False, uncompared=["a reason"])
    assert part.status == "PARTIAL" and not part.reproduced and part.fraction == pytest.approx(0.205)
    assert part.verdict().startswith("verdict: PARTIAL: compared only 0.410 s of the 2.000 s recorded (20.5 %): "
                                     "a reason; the part compared matches")
    d = part.to_dict()
    assert d["status"] == "PARTIAL" and d["reproduced"] is False and d["fraction"] == pytest.approx(0.205)
    # a difference beyond the tolerance is DIFFERS, whatever the coverage
    off = result(compared_samples=20, compared_duration=0.41, complete=False, max_omega_h_error=10 * RATE_TOLERANCE)
    assert off.status == "DIFFERS" and "omega_h by" in off.verdict() and "(20.5 %)" in off.verdict()
    assert result(max_position_error=2 * POSITION_TOLERANCE).status == "DIFFERS"
    assert result(compared_samples=0, compared_duration=0.0, complete=False).status == "NOT CHECKED"


def test_the_sample_recording_with_a_reversal_is_compared_whole():
    """bags/design2_n2_reversal.mcap (bags/make_samples.sh): +50, -50, 0, +50 rpm. The old rule stopped at the
    reversal (8.0 s of 32.2 s) and still said REPRODUCED."""
    from pathlib import Path

    from flagbot_sim.runs.resim import resimulate
    res = resimulate(Path(__file__).resolve().parents[1] / "bags" / "design2_n2_reversal.mcap")
    commands = [w for _, w in res.commands]
    assert min(commands) < 0 < max(commands) and 0.0 in commands[1:]
    assert res.status == "REPRODUCED" and res.complete and res.fraction == 1.0, res.verdict()
    assert res.recorded_duration > 30 and res.compared_samples == res.samples - 1
