"""Motor-speed profiles: constant, steps, ramp, square wave. Pure functions of time (no ROS), in rad/s."""
from __future__ import annotations

import math
from dataclasses import dataclass

from .cliutil import finite_float
from .units import RPM


class ProfileError(ValueError):
    pass


@dataclass(frozen=True)
class Profile:
    """Piecewise-linear omega_T(t): breakpoints (t_i, omega_i); a jump is two breakpoints at the same time."""
    times: tuple
    values: tuple
    loop: bool = False

    @property
    def duration(self) -> float:
        return self.times[-1]

    def value(self, t: float) -> float:
        if self.loop and self.duration > 0:
            t = math.fmod(t, self.duration)
        if t <= self.times[0]:
            return self.values[0]
        if t >= self.times[-1]:
            return self.values[-1]
        # last breakpoint at or before t (so that a jump takes the new value exactly at its time)
        i = max(k for k in range(len(self.times)) if self.times[k] <= t)
        if i + 1 >= len(self.times) or self.times[i + 1] == self.times[i]:
            return self.values[i]
        t0, t1 = self.times[i], self.times[i + 1]
        w = (t - t0) / (t1 - t0)
        return self.values[i] + w * (self.values[i + 1] - self.values[i])

    def segments(self) -> list[tuple[float, float, float]]:
        """(start, end, value) of each constant stretch: what a step profile's table reports."""
        out = []
        for i in range(len(self.times) - 1):
            if self.values[i] == self.values[i + 1] and self.times[i + 1] > self.times[i]:
                out.append((self.times[i], self.times[i + 1], self.values[i]))
        return out


def _num(text: str, what: str) -> float:
    return finite_float(text, what, ProfileError)


def _dur(text: str, what: str) -> float:
    v = _num(text, what)
    if v <= 0:
        raise ProfileError(f"{what} must be positive, got {v:g} s")
    return v


def constant(value: float, duration: float = 0.0) -> Profile:
    return Profile((0.0, max(duration, 0.0)), (value, value))


def steps(pairs: list[tuple[float, float]], loop: bool = False) -> Profile:
    """[(value, duration), ...]: hold each value for its duration."""
    times, values, t = [], [], 0.0
    for v, d in pairs:
        times += [t, t + d]
        values += [v, v]
        t += d
    return Profile(tuple(times), tuple(values), loop)


def ramp(v0: float, v1: float, duration: float, loop: bool = False) -> Profile:
    return Profile((0.0, duration), (v0, v1), loop)


def square(low: float, high: float, period: float, cycles: int = 1, loop: bool = False) -> Profile:
    return steps([(low, period / 2), (high, period / 2)] * cycles + [(low, period / 2)], loop)


def parse(kind: str, args: list[str], rpm: bool = False, loop: bool = False) -> Profile:
    """Build a profile from command-line words; values in rad/s, or rpm with ``rpm=True``."""
    k = RPM if rpm else 1.0
    unit = "rpm" if rpm else "rad/s"
    if kind == "constant":
        if len(args) != 1:
            raise ProfileError(f"constant takes one value ({unit}), got {args}")
        return constant(k * _num(args[0], "constant value"))
    if kind == "steps":
        if len(args) != 1 or not args[0]:
            raise ProfileError("steps takes one argument: VALUE:SECONDS,VALUE:SECONDS,...")
        pairs = []
        for item in args[0].split(","):
            if ":" not in item:
                raise ProfileError(f"steps: {item!r} must be VALUE:SECONDS")
            v, d = item.split(":", 1)
            pairs.append((k * _num(v, f"step value in {item!r}"), _dur(d, f"step duration in {item!r}")))
        return steps(pairs, loop)
    if kind == "ramp":
        if len(args) != 3:
            raise ProfileError(f"ramp takes FROM TO SECONDS, got {args}")
        return ramp(k * _num(args[0], "ramp start"), k * _num(args[1], "ramp end"), _dur(args[2], "ramp duration"),
                    loop)
    if kind == "square":
        if len(args) not in (3, 4):
            raise ProfileError(f"square takes LOW HIGH PERIOD [CYCLES], got {args}")
        cycles = int(args[3]) if len(args) == 4 else 1
        if cycles < 1:
            raise ProfileError(f"square: CYCLES must be >= 1, got {cycles}")
        return square(k * _num(args[0], "square low"), k * _num(args[1], "square high"),
                      _dur(args[2], "square period"), cycles, loop)
    raise ProfileError(f"unknown profile {kind!r}: choose constant, steps, ramp or square")
