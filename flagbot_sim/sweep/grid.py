"""The sweep grid: ``--grid KEY=VALUES`` specifications, expanded to points and validated against the scene.

VALUES is a comma-separated list whose items are TOML values (``2``, ``0.13``, ``"splu"``) or inclusive ranges
``start:stop:step`` (``20:250:10`` is 20, 30, ..., 250). KEY is any scene key ``section.key`` or a shorthand
(``n``, ``L``, ``rpm``). Every point is built into a scene before anything runs, so a bad key, a bad value or a
combination the scene refuses (edge longer than the flagellum, ...) is one error naming the key.
"""
from __future__ import annotations

import itertools
import tomllib
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation

from ..scene import Scene, SceneError, _split_key, inert_keys

#: shorthand grid keys; the CSV and the manifest always use the full scene key
ALIASES = {"n": "robot.n_flagella", "L": "flagellum.length", "rpm": "motor.omega_rpm"}

#: refuse grids larger than this: a typo such as 20:250:0.001 should not start a week-long sweep
MAX_POINTS = 100_000


class SweepError(SceneError):
    """A sweep request that cannot run (bad grid, a different sweep already in --out, ...): one-line message."""


@dataclass(frozen=True)
class Point:
    """One grid point: the values of the grid keys, in grid order."""

    values: tuple  # ((key, value), ...)

    @property
    def key(self) -> str:
        """Resume key: the point's parameters, exactly (repr round-trips floats)."""
        return ";".join(f"{k}={v!r}" for k, v in self.values)

    def overrides(self) -> dict:
        return dict(self.values)


def canonical_key(key: str) -> str:
    key = key.strip()
    key = ALIASES.get(key, key)
    _split_key(key)   # SceneError naming the key and listing the valid ones
    return key


def _range_values(key: str, item: str) -> list:
    parts = item.split(":")
    if len(parts) != 3:
        raise SweepError(f"--grid {key}: range {item!r} must be start:stop:step, e.g. 20:250:10")
    try:
        start, stop, step = (Decimal(p.strip()) for p in parts)
    except InvalidOperation:
        raise SweepError(f"--grid {key}: range {item!r} must be three numbers start:stop:step") from None
    if not all(x.is_finite() for x in (start, stop, step)):
        raise SweepError(f"--grid {key}: range {item!r} must be finite numbers")
    if step <= 0:
        raise SweepError(f"--grid {key}: range {item!r} needs a positive step")
    if stop < start:
        raise SweepError(f"--grid {key}: range {item!r} has stop < start")
    count = int((stop - start) / step) + 1     # Decimal: 20:250:10 has exactly 24 values, no float drift
    if count > MAX_POINTS:
        raise SweepError(f"--grid {key}: range {item!r} has {count} values (limit {MAX_POINTS})")
    values = [start + i * step for i in range(count)]
    if all(v == v.to_integral_value() for v in values):
        return [int(v) for v in values]
    return [float(v) for v in values]


def parse_values(key: str, text: str) -> list:
    values = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            raise SweepError(f"--grid {key}: empty value in {text!r}")
        if ":" in item and not item.startswith(("'", '"', "[")):
            values.extend(_range_values(key, item))
            continue
        try:
            values.append(tomllib.loads(f"v = {item}")["v"])
        except tomllib.TOMLDecodeError:
            values.append(item)     # a bare word: a string (the scene check decides whether that is allowed)
    return values


def parse_grid(specs: list[str]) -> dict[str, list]:
    """``["n=2,3", "motor.omega_rpm=20:250:10"]`` -> {"robot.n_flagella": [2, 3], "motor.omega_rpm": [...]}."""
    grid: dict[str, list] = {}
    for spec in specs:
        if "=" not in spec:
            raise SweepError(f"--grid {spec!r} must look like KEY=VALUES, e.g. n=2,3 or motor.omega_rpm=20:250:10")
        raw_key, text = spec.split("=", 1)
        try:
            key = canonical_key(raw_key)
        except SceneError as exc:
            raise SweepError(f"--grid {raw_key.strip()}: {exc}") from None
        if key in grid:
            raise SweepError(f"--grid {key} is given twice")
        values = parse_values(key, text)
        seen = set()
        for v in values:
            if repr(v) in seen:
                raise SweepError(f"--grid {key}: value {v!r} is listed twice")
            seen.add(repr(v))
        grid[key] = values
    return grid


def expand(grid: dict[str, list]) -> list[Point]:
    keys = list(grid)
    combos = list(itertools.product(*(grid[k] for k in keys)))
    if len(combos) > MAX_POINTS:
        raise SweepError(f"the grid has {len(combos)} points (limit {MAX_POINTS})")
    return [Point(tuple(zip(keys, combo))) for combo in combos]


def validate(base: Scene, grid: dict[str, list], fixed_overrides: dict) -> tuple[dict[str, list], list[Point]]:
    """Check every value of every key against the scene, then every point; return the grid with values
    normalised by the scene's types (n=2.0 -> 2) and its points."""
    clash = sorted(set(grid) & set(fixed_overrides))
    if clash:
        raise SweepError(f"{clash[0]} is both a --set and a --grid key; keep one")
    inert = inert_keys(base)
    normalised: dict[str, list] = {}
    for key, values in grid.items():
        if key in inert:
            raise SweepError(f"--grid {inert[key]}")
        section, name = key.split(".", 1)
        out = []
        for v in values:
            try:
                scene = base.with_overrides({key: v})
            except SceneError as exc:
                raise SweepError(f"--grid {key}: {exc}") from None
            out.append(getattr(getattr(scene, section), name))
        if len({repr(v) for v in out}) != len(out):
            raise SweepError(f"--grid {key}: values {values} repeat after conversion to the key's type")
        normalised[key] = out
    points = expand(normalised)
    for p in points:
        try:
            scene = base.with_overrides(p.overrides())
        except SceneError as exc:
            raise SweepError(f"grid point {p.key}: {exc}") from None
        if scene.clamped:
            raise SweepError(f"scene {base.scene.name!r} is a clamped flagellum; sweeps need a free robot "
                             "(head_drag, head_torque, motor)")
    return normalised, points
