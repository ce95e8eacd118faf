"""Measured steady states (DATA.csv): one row per experiment, its inputs and its measured outputs.

Input columns are scene keys (``section.key``) or the sweep CSV's shorthands: ``n`` (robot.n_flagella), ``L``
(flagellum.length), ``omega_T_rpm`` / ``rpm`` / ``omega_rpm`` (motor.omega_rpm), ``omega_T`` (rad/s, converted
to rpm). Output columns: ``v`` (m/s, positive = head first) and/or ``omega_h`` (rad/s), with optional ``v_std`` /
``omega_h_std`` (standard deviations, same units) as weights. Any other column is ignored, so a sweep's own
``results.csv`` is valid input: only its ``framework == der`` rows are used, and rows with an ``error`` are
left out. A column that looks like a scene key but is not one is an error (a misspelt input would otherwise be
silently dropped).
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

from ..cliutil import finite_float
from ..scene import SECTIONS, Scene, SceneError, _split_key
from ..units import RPM

#: output columns that can be fitted, with their units
OUTPUTS = {"v": "m/s", "omega_h": "rad/s"}
#: input shorthands -> scene keys (the sweep CSV's columns and the sweep grid's aliases)
ALIASES = {"n": "robot.n_flagella", "L": "flagellum.length", "omega_T_rpm": "motor.omega_rpm",
           "rpm": "motor.omega_rpm", "omega_rpm": "motor.omega_rpm"}
#: the motor speed in rad/s (the sweep CSV's omega_T): converted to motor.omega_rpm
RAD_PER_S = {"omega_T": "motor.omega_rpm"}

MAX_ROWS = 100_000


class DataError(SceneError):
    """DATA.csv cannot be used: the message names the file, the line and the column."""


@dataclass
class DataRow:
    line: int                         # line number in the file (the header is line 1)
    overrides: dict                   # scene key -> value
    values: dict                      # output -> measured value (only the outputs measured in this row)
    std: dict                         # output -> its standard deviation, or None (no std column)

    def label(self) -> str:
        return ", ".join(f"{_short_key(k)}={_fmt(v)}" for k, v in self.overrides.items()) or "(scene as given)"


@dataclass
class Dataset:
    path: str
    rows: list[DataRow]
    outputs: list[str]                # outputs present in at least one row, in OUTPUTS order
    inputs: list[str]                 # scene keys given by the columns
    ignored: list[str] = field(default_factory=list)    # columns not used
    dropped: int = 0                  # rows left out (not framework der, or with an error)

    def sigma(self, output: str) -> float:
        """The weight scale of an output without a std column: the RMS of its measured values (so each output
        counts by its relative misfit; the confidence intervals do not depend on this scale)."""
        ys = [r.values[output] for r in self.rows if output in r.values]
        rms = math.sqrt(sum(y * y for y in ys) / len(ys)) if ys else 0.0
        return rms if rms > 0 else 1.0

    def weights(self) -> list[list[tuple[str, float, float]]]:
        """Per row: (output, measured value, standard deviation used) for each measured output."""
        default = {o: self.sigma(o) for o in self.outputs}
        return [[(o, r.values[o], r.std[o] if r.std.get(o) is not None else default[o])
                 for o in self.outputs if o in r.values] for r in self.rows]


def _short_key(key: str) -> str:
    short = {v: k for k, v in (("n", "robot.n_flagella"), ("L", "flagellum.length"), ("rpm", "motor.omega_rpm"))}
    return short.get(key, key)


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _column_key(name: str) -> str | None:
    """The scene key a column gives, None for a column that is not an input."""
    if name in ALIASES:
        return ALIASES[name]
    if name in RAD_PER_S:
        return RAD_PER_S[name]
    if "." in name and name.split(".", 1)[0] in SECTIONS:
        _split_key(name)                 # a SceneError naming the key and listing the valid ones
        return name
    return None


def _number(text: str, where: str) -> float | None:
    text = text.strip()
    if text == "" or text.lower() in ("nan", "none", "null"):
        return None
    return finite_float(text, where, DataError)


def read_data(path: str | Path, base: Scene, exclude: tuple[str, ...] = ()) -> Dataset:
    """Read and check DATA.csv against the scene: every row's overrides must make a valid scene.

    ``exclude``: scene keys that must not be data columns (the fitted parameters)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"data file {path} does not exist (or is not a regular file)")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"data file {path} cannot be read: {exc}") from None
    reader = csv.reader(text.splitlines())
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise DataError(f"data file {path} is empty: it needs a header line and one row per experiment") from None
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise DataError(f"{path}: column(s) {', '.join(dup)} appear twice in the header")
    keys: dict[str, str] = {}
    ignored = []
    for h in header:
        try:
            k = _column_key(h)
        except SceneError as exc:
            raise DataError(f"{path}: column {h!r} is not a scene key ({exc})") from None
        if k is None:
            if h not in OUTPUTS and h not in (f"{o}_std" for o in OUTPUTS):
                ignored.append(h)
        else:
            keys[h] = k
    clash = sorted(set(keys.values()) & set(exclude))
    if clash:
        raise DataError(f"{path}: {clash[0]} is both a fitted parameter and a data column; fit it or give it, "
                        "not both")
    outputs = [o for o in OUTPUTS if o in header]
    if not outputs:
        raise DataError(f"{path}: no output column; give v (m/s) and/or omega_h (rad/s) (columns: "
                        f"{', '.join(header)})")
    for o in OUTPUTS:
        if f"{o}_std" in header and o not in header:
            raise DataError(f"{path}: column {o}_std without a {o} column")
    rows, dropped = [], 0
    for lineno, values in enumerate(reader, start=2):
        if not any(v.strip() for v in values):
            continue                                   # a blank line
        if len(values) != len(header):
            raise DataError(f"{path}, line {lineno}: {len(values)} fields, the header has {len(header)}")
        rec = dict(zip(header, values))
        if "framework" in rec and rec["framework"].strip() != "der":
            dropped += 1
            continue
        if "error" in rec and rec["error"].strip():
            dropped += 1
            continue
        overrides: dict = {}
        for col, key in keys.items():
            x = _number(rec[col], f"{path}, line {lineno}, column {col}")
            if x is None:
                continue
            if col in RAD_PER_S:
                x = x / RPM
            value = int(x) if key == "robot.n_flagella" and float(x).is_integer() else x
            if key in overrides and not _same(overrides[key], value):
                raise DataError(f"{path}, line {lineno}: columns give {key} = {overrides[key]!r} and {value!r}")
            overrides.setdefault(key, value)
        measured, std = {}, {}
        for o in outputs:
            y = _number(rec[o], f"{path}, line {lineno}, column {o}")
            if y is None:
                continue
            measured[o] = y
            std[o] = None
            if f"{o}_std" in rec:
                s = _number(rec[f"{o}_std"], f"{path}, line {lineno}, column {o}_std")
                if s is None or s <= 0:
                    raise DataError(f"{path}, line {lineno}: {o}_std must be a positive number where {o} is "
                                    f"given, got {rec[f'{o}_std']!r}")
                std[o] = s
        if not measured:
            raise DataError(f"{path}, line {lineno}: no measured value (columns {', '.join(outputs)} are empty)")
        try:
            base.with_overrides(overrides)
        except SceneError as exc:
            raise DataError(f"{path}, line {lineno}: {exc}") from None
        rows.append(DataRow(lineno, overrides, measured, std))
        if len(rows) > MAX_ROWS:
            raise DataError(f"{path}: more than {MAX_ROWS} rows")
    if not rows:
        raise DataError(f"{path}: no usable rows ({dropped} left out: not framework 'der', or with an error)")
    return Dataset(str(path), rows, [o for o in outputs if any(o in r.values for r in rows)],
                   sorted(set(keys.values())), ignored, dropped)


def _same(a, b) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, (int, float)) and math.isclose(a, b, rel_tol=1e-9))


def engine_rows(data: Dataset) -> list[dict]:
    """The rows as :func:`flagbot_sim.fit.evaluate.make_tasks` takes them."""
    return [{"index": i, "overrides": r.overrides} for i, r in enumerate(data.rows)]
