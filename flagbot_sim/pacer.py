"""Real-time pacing of a simulation, without ROS: how far to step at each tick of a wall-clock timer.

The live device (sim_node) steps its simulation in a timer. At every tick the pacer computes the simulated time
the run should have reached at the requested real-time factor (``rtf``; 0 = as fast as possible), steps towards
it for at most a budget of wall time (the rest of the tick serves commands and services), and keeps score:

* the achieved real-time factor over the last ``window`` seconds of wall time;
* whether the run falls behind: the achieved factor is below (1 - BEHIND_TOL) of the requested one over at least
  half a window, or this tick ended more than two steps (or two ticks' worth of simulated time) short of its
  target;
* catch-up debt: more than a second of wall time behind, the schedule is re-anchored at the present instead of
  racing to make up time that a command sent now would not care about; the simulated time so given up is summed
  in ``given_up``.

Judged on the tick alone, a run whose every step outlasts a second (Newton cut to tiny sub-steps) looked on time
at every other tick: the re-anchoring set the target back to the present, so the next tick started with no lag.
The achieved rate over the window does not forget.

It works with fixed steps (``dt``: a step is taken while at least half of it fits before the target) and with
error-controlled ones (``dt`` None: steps of the size the simulation picks, while the target is ahead); either
way simulated time only grows, so /clock is monotone.

The steps of a tick go in batches (one compiled call each: Simulation.advance), as many as take half the
budget left at the stepping rate the pacer has seen (one step while it has seen none), so a tick spends its
budget in a few calls instead of one call per step, and overruns it by at most the half it allowed a batch.
"""
from __future__ import annotations

import math
import time
from collections import deque
from typing import Callable


#: behind when the achieved real-time factor is below (1 - BEHIND_TOL) of the requested one
BEHIND_TOL = 0.1


class Pacer:
    def __init__(self, rtf: float, sim_time: float, clock: Callable[[], float] = time.monotonic,
                 window: float = 2.0):
        self.clock = clock
        self.window = float(window)
        self.rtf = float(rtf)
        self.behind = False
        self.lag = 0.0                  # s of simulated time the last tick ended short of its target
        self.given_up = 0.0             # s of simulated time given up by re-anchoring, in total
        self._samples: deque[tuple[float, float]] = deque()      # (wall, simulated time), last window
        self.step_rate = 0.0            # steps per second of wall time while stepping (0: not seen yet)
        self.anchor(sim_time)

    def anchor(self, sim_time: float, wall: float | None = None) -> None:
        """Start the schedule afresh: simulated time ``sim_time`` now (after a reset, a pause, an rtf change)."""
        self._wall0 = self.clock() if wall is None else wall
        self._sim0 = float(sim_time)

    def set_rtf(self, rtf: float, sim_time: float) -> None:
        self.rtf = float(rtf)
        self.anchor(sim_time)
        self.restart_window()           # the rate achieved at the old factor says nothing about the new one

    def target(self, wall: float) -> float:
        """Simulated time the run should have reached at wall time ``wall``."""
        return self._sim0 + self.rtf * (wall - self._wall0)

    def advance(self, sim_time: Callable[[], float], steps: Callable[[int, float], int | None], budget: float,
                dt: float | None, tick_period: float, log_time: Callable[[], float] | None = None) -> bool:
        """Step towards the target for at most ``budget`` seconds of wall time. ``steps(n, t_stop)`` takes up to
        n steps, none from a simulated time >= t_stop, and returns how many it took (None: a step failed);
        ``sim_time()`` is the simulation's time, ``dt`` its fixed step (None: error-controlled), ``log_time()``
        the monotone time the achieved rate is measured on (default sim_time). Returns False if a step failed."""
        start = self.clock()
        ok = True
        if self.rtf > 0:
            target = self.target(start)
            # a fixed step is taken while t + dt / 2 <= target, an error-controlled one while t < target
            t_stop = math.nextafter(target - 0.5 * dt, math.inf) if dt is not None else target
            while sim_time() < t_stop and self.clock() - start < budget:
                taken = self._batch(steps, t_stop, budget - (self.clock() - start))
                if taken is None:
                    ok = False
                    break
                if taken == 0:
                    break
            lag = target - sim_time()
            self.lag = max(0.0, lag)
            short = lag > max(2.0 * (dt or 0.0), self.rtf * 2.0 * tick_period)
            if lag > self.rtf * 1.0:       # more than a second of wall time behind: stop accumulating debt
                now = self.clock()
                self.given_up += self.target(now) - sim_time()      # the whole debt, this tick's stepping too
                self.anchor(sim_time(), now)
        else:
            short = False
            self.lag = 0.0
            while True:
                taken = self._batch(steps, math.inf, budget - (self.clock() - start))
                if taken is None:
                    ok = False
                    break
                if taken == 0 or self.clock() - start >= budget:
                    break
        now = self.clock()
        self._samples.append((now, (log_time or sim_time)()))
        while self._samples[0][0] <= now - self.window:      # in wall-time order: the old ones are first
            self._samples.popleft()
        self.behind = self.rtf > 0 and (short or self._slow())
        return ok

    def _batch(self, steps: Callable[[int, float], int | None], t_stop: float, left: float) -> int | None:
        """One call of ``steps``: as many steps as take half the ``left`` budget at the rate seen so far (at
        least one); learns the rate from it."""
        n = max(1, int(0.5 * left * self.step_rate)) if self.step_rate > 0 else 1
        t0 = self.clock()
        taken = steps(n, t_stop)
        spent = self.clock() - t0
        if taken and spent > 0:
            rate = taken / spent
            self.step_rate = rate if self.step_rate <= 0 else 0.5 * (self.step_rate + rate)
        return taken

    def _slow(self) -> bool:
        """The achieved factor, over at least half a window, is below (1 - BEHIND_TOL) of the requested one."""
        rate = self.achieved()
        return (rate is not None and self._samples[-1][0] - self._samples[0][0] >= 0.5 * self.window
                and rate < (1.0 - BEHIND_TOL) * self.rtf)

    def achieved(self) -> float | None:
        """Real-time factor achieved over the last window of wall time (None before two samples)."""
        if len(self._samples) < 2 or self._samples[-1][0] <= self._samples[0][0]:
            return None
        (w0, s0), (w1, s1) = self._samples[0], self._samples[-1]
        return (s1 - s0) / (w1 - w0)

    def restart_window(self) -> None:
        """Forget the achieved-rate samples and the verdict on them (a pause, a rebuilt or reset simulation, a new
        rate: what was achieved before says nothing about what comes next)."""
        self._samples.clear()
        self.behind = False
        self.lag = 0.0
