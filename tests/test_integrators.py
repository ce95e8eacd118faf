"""The time integrators and the error control (physics/stepper.py): orders of convergence, step sizes that follow
the motion, the bound on the drive's turn per step, and an achieved accuracy that tracks the requested one.

References: a much finer run of the same scene (orders), and the steady solver (physics/steady.py), whose answer
is the dt -> 0 limit of time stepping at the same discretisation (error control, 5000 rpm)."""
import math

import numpy as np
import pytest

from flagbot_sim.physics import Simulation
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.physics.steady import SteadySolver, summary
from flagbot_sim.scene import load_scene
from flagbot_sim.units import RPM

DESIGN2_CLAMPED = ["flagellum.length=0.089", "medium.mu=2.125", "plate.diameter=0.03"]   # as in conftest.py
SHORT = ["flagellum.length=0.05", "flagellum.edge_length=0.005"]     # a short clamped flagellum: 10 edges


def clamped(*over):
    return Simulation(load_scene("clamped_flagellum", [*SHORT, *over]))


def steady_outputs(scene, over):
    sc = load_scene(scene, over)
    m = RobotModel(sc)
    return summary(m, SteadySolver(m).solve(sc.omega_T))


def output_error(got, ref, sc) -> float:
    """Largest relative error of Fx, Tx and the tip (the tip against its deflection from the straight rod)."""
    straight = np.array([sc.flagellum.length, sc.R_d, 0.0])
    tip, tr = np.asarray(got["tip"]), np.asarray(ref["tip"])
    return max(abs(got["Fx"] / ref["Fx"] - 1), abs(got["Tx"] / ref["Tx"] - 1),
               np.linalg.norm(tip - tr) / np.linalg.norm(tr - straight))


@pytest.fixture(scope="module")
def transient_reference():
    """The first second after the clamp starts turning at 60 rpm, BDF2 at dt = 1e-2 / 32."""
    sim = clamped("motor.omega_rpm=60", "time.integrator='bdf2'", f"time.dt={1e-2 / 32}")
    sim.run(1.0)
    x = sim.positions()
    return x, np.linalg.norm(x[-1] - np.array([0.05, sim.scene.R_d, 0.0]))


@pytest.mark.parametrize("integrator,order", [("implicit_euler", 1), ("bdf2", 2)])
def test_order_of_convergence_on_a_transient(transient_reference, integrator, order):
    """Errors of the node positions at t = 1 s (the flagellum still bending) at dt, dt/2, dt/4: halving dt
    divides them by 2^order. [measured: implicit Euler 1.99, 2.00; BDF2 4.17, 4.38; 4.5% vs 0.36% at dt]"""
    x_ref, deflection = transient_reference
    errs = []
    for dt in (2e-2, 1e-2, 5e-3):
        sim = clamped("motor.omega_rpm=60", f"time.integrator='{integrator}'", f"time.dt={dt}")
        sim.run(1.0)
        errs.append(np.abs(sim.positions() - x_ref).max() / deflection)
    orders = [math.log2(errs[i] / errs[i + 1]) for i in range(2)]
    assert all(abs(p - order) < 0.25 for p in orders), (errs, orders)
    assert errs[0] < (0.06 if order == 1 else 0.005)


def test_error_control_grows_steps_in_steady_rotation_and_shrinks_them_at_a_command_change():
    """rtol = 1e-3, largest step 1 s. From rest at 30 rpm the steps grow to a plateau set by the rotation
    (omega h ~ 0.03); at a step of the command to 60 rpm they collapse (rejected attempts), then grow back to a
    plateau half as long (omega h unchanged). [plateaus 9.5e-3 s and 4.8e-3 s; smallest step after the change
    2.5e-5 s; back to 3e-3 s within 0.05 s]"""
    sim = clamped("motor.omega_rpm=30", "time.rtol=1e-3", "time.dt=1.0")
    rec = []

    def run_to(t_end):
        while sim.time < t_end:
            st = sim.step()
            assert st.substeps == 1 and st.error <= 1.0
            rec.append((sim.time, st.substep_dts[0], st.rejections))
    run_to(4.0)
    t, h, rej = (np.array(c) for c in zip(*rec))
    plateau = h[t > 2.0]
    assert plateau.max() < 1.05 * plateau.min()                  # steady rotation, steady step
    assert 0.008 < plateau.mean() < 0.012 and sim.omega_T * plateau.mean() < 0.04
    assert plateau.mean() > 5 * h[3:].min()                      # grown from the start-up transient
    assert np.all(h[3:] / h[2:-1] <= 2.0 + 1e-12)                 # at most doubling (BDF2's zero-stability)
    n0 = len(rec)
    sim.set_omega(60 * RPM)
    run_to(6.0)
    t2, h2, rej2 = (np.array(c) for c in zip(*rec[n0:]))
    assert rej2[:5].sum() > 0                                    # the old step was refused at the change
    assert h2[t2 < 4.05].min() < 0.01 * plateau.mean()           # collapsed through the transient
    new = h2[t2 > 5.0]
    assert new.max() < 1.05 * new.min()
    assert new.mean() / plateau.mean() == pytest.approx(0.5, abs=0.05)
    assert h2[(t2 > 4.2) & (t2 < 5.0)].min() > 0.8 * new.mean()  # back within 0.2 s


def test_the_drive_turns_at_most_max_turn_per_step_and_5000_rpm_does_not_alias():
    """Design 2's clamped flagellum at 5000 rpm with the default dt = 1e-2 s, where one step would turn the clamp
    by 5.24 rad = 2 pi - 1.05 rad and the run would show the 1000-rpm state mirrored (Fx unchanged, Tx reversed).
    The drive turns at most time.max_turn (0.5 rad) per sub-step and the answer is the 5000-rpm one: against
    the steady solver at 5000 rpm. Without inertia here: at 5000 rpm the centrifugal load (rho A omega^2 R, ~3x
    the drag) makes the flagellum whirl off the steady branch the solver follows, into a folded state.
    [max_turn 0.5: Fx 6.7%, Tx 4.6% off; max_turn 0.1: 0.6%, 0.2%]"""
    over = [*DESIGN2_CLAMPED, "scene.effects=['rft','clamp']"]
    ref = steady_outputs("clamped_flagellum", over + ["motor.omega_rpm=5000"])
    slow = steady_outputs("clamped_flagellum", over + ["motor.omega_rpm=1000"])
    for max_turn, tol in ((0.5, 0.15), (0.1, 0.02)):
        sim = Simulation(load_scene("clamped_flagellum", over + ["motor.omega_rpm=5000", f"time.max_turn={max_turn}"]))
        assert sim.dt == 1e-2 and sim.omega_T * sim.dt > 5.0
        turns = []
        for _ in range(120):
            st = sim.step()
            assert sum(st.substep_dts) == pytest.approx(sim.dt, rel=1e-12)
            turns += [sim.omega_T * h for h in st.substep_dts]
        assert max(turns) <= max_turn * (1 + 1e-9) and len(turns) >= 120 * math.ceil(sim.omega_T * sim.dt / max_turn)
        assert sim.motor_angle == pytest.approx(sim.omega_T * 1.2, rel=1e-12)
        got = sim.summary()
        assert got["Fx"] == pytest.approx(ref["Fx"], rel=tol) and got["Tx"] == pytest.approx(ref["Tx"], rel=tol)
        assert got["Tx"] * slow["Tx"] > 0                           # not reversed
        assert abs(got["Fx"] - slow["Fx"]) > 3 * abs(got["Fx"] - ref["Fx"])


def test_achieved_accuracy_tracks_the_requested_tolerance():
    """Design 2's clamped flagellum at 10 rpm, BDF2 from rest to a steady state: rtol = 1e-2 and 1e-3 give
    errors below rtol, in the ratio of the tolerances. [0.53 and 0.54 rtol]"""
    over = [*DESIGN2_CLAMPED, "motor.omega_rpm=10"]
    ref = steady_outputs("clamped_flagellum", over)
    err = {}
    for rtol in (1e-2, 1e-3):
        sc = load_scene("clamped_flagellum", over + [f"time.rtol={rtol}", "time.dt=1.0", "observe.steady_rtol=1e-6"])
        sim = Simulation(sc)
        assert sim.run_until_steady(60.0)
        err[rtol] = output_error(sim.summary(), ref, sc)
        assert 0.2 * rtol < err[rtol] < rtol, (rtol, err[rtol])
    assert 5.0 < err[1e-2] / err[1e-3] < 20.0
