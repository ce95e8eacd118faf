"""The sweep directory: ``sweep.json`` (what is being swept), ``scene.toml`` and ``results.csv`` (tidy, one row
per grid point and framework, appended and flushed as each point finishes).

Resume: a point is done when the CSV holds one row for each of its frameworks. On restart the CSV is read back,
a torn last line (a kill in the middle of a write) and the rows of incomplete points are dropped (the file is
rewritten atomically if anything was dropped), and only the missing points are computed. The manifest's
identity (resolved scene values, grid, steady-state settings, frameworks) must match the new request exactly,
else the sweep is refused: mixing results of two different sweeps in one CSV would be silently wrong.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import time
from pathlib import Path

from ..cliutil import dumps, json_output, make_out_dir
from .grid import Point, SweepError

FORMAT = "flagbot_sim sweep 2"
MANIFEST = "sweep.json"
RESULTS = "results.csv"

#: the DER rows' estimated relative numerical errors (physics/error_estimate.py): of each output (time + space),
#: and the time and space parts' largest over the outputs (NaN where a part does not exist: no time part for a
#: steady solve; beam rows have none)
ERROR_COLUMNS = ["error_estimate_omega_h", "error_estimate_omega_t", "error_estimate_v", "error_estimate_time",
                 "error_estimate_space"]
#: columns after the grid keys' own columns
VALUE_COLUMNS = ["n", "L", "omega_T", "omega_T_rpm", "framework", "omega_h", "omega_t", "v", "omega_T_bar",
                 "omega_h_bar", "v_bar", "w_tip_over_L", "motor_torque", "power", "cost_of_transport", "method",
                 "stable", "residual", "converged", "hit_cap", "steps", "sim_time", "change_omega_h", "change_v",
                 *ERROR_COLUMNS, "wall_seconds", "worker", "finished_at", "error"]
FLOAT_COLUMNS = {"L", "omega_T", "omega_T_rpm", "omega_h", "omega_t", "v", "omega_T_bar", "omega_h_bar", "v_bar",
                 "w_tip_over_L", "motor_torque", "power", "cost_of_transport", "residual", "sim_time",
                 "change_omega_h", "change_v", "wall_seconds", "finished_at", *ERROR_COLUMNS}
INT_COLUMNS = {"n", "steps"}
BOOL_COLUMNS = {"converged", "hit_cap"}


def columns(grid_keys: list[str]) -> list[str]:
    return ["point", *grid_keys, *VALUE_COLUMNS]


def _jsonable(x):
    """``x`` as strict JSON gives it back (numpy values converted, NaN/Inf as None): what the manifest stores."""
    return json.loads(dumps(x))


def manifest_identity(scene_flat: dict, grid: dict, settings: dict, frameworks: list[str]) -> dict:
    return _jsonable({"format": FORMAT, "scene": scene_flat, "grid": grid, "settings": settings,
                      "frameworks": list(frameworks)})


def _describe_difference(old: dict, new: dict) -> str:
    for part in ("format", "grid", "settings", "frameworks", "scene"):
        a, b = old.get(part), new.get(part)
        if a == b:
            continue
        if isinstance(a, dict) and isinstance(b, dict):
            for k in sorted(set(a) | set(b)):
                if a.get(k) != b.get(k):
                    return f"{part} {k}: stored {a.get(k)!r}, now {b.get(k)!r}"
        return f"{part}: stored {a!r}, now {b!r}"
    return "unknown difference"


def parse_row(row: dict) -> dict:
    out = dict(row)
    for k in FLOAT_COLUMNS:
        if k in out:
            out[k] = float(out[k]) if out[k] not in ("", None) else math.nan
    for k in INT_COLUMNS:
        if k in out:
            out[k] = int(out[k])
    for k in BOOL_COLUMNS:
        if k in out:
            if out[k] not in ("True", "False"):
                raise ValueError(f"{k} = {out[k]!r}")
            out[k] = out[k] == "True"
    return out


def read_csv(path: str | Path) -> tuple[list[str], list[dict], bool]:
    """(header, parsed rows, clean): rows that do not parse (a torn last line) are skipped and clean is False."""
    text = Path(path).read_text()
    clean = True
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]   # the last line was being written when the sweep was killed
        clean = False
    reader = csv.reader(io.StringIO(text))
    try:
        header = next(reader)
    except StopIteration:
        return [], [], False
    rows = []
    for values in reader:
        if len(values) != len(header):
            clean = False
            continue
        try:
            rows.append(parse_row(dict(zip(header, values))))
        except ValueError:
            clean = False
    return header, rows, clean


def read_results(directory: str | Path) -> list[dict]:
    """The rows of a sweep's CSV (complete lines only), numbers parsed."""
    path = Path(directory) / RESULTS
    if not path.exists():
        raise SweepError(f"{path} does not exist: not a sweep directory (run `flagbot sweep ... --out DIR`)")
    return read_csv(path)[1]


def read_manifest(directory: str | Path) -> dict:
    path = Path(directory) / MANIFEST
    if not path.exists():
        raise SweepError(f"{path} does not exist: not a sweep directory")
    return json.loads(path.read_text())


class SweepStore:
    """Owns DIR: checks or writes the manifest, finds finished points, appends rows."""

    def __init__(self, directory: str | Path, grid: dict, points: list[Point], identity: dict, extra: dict,
                 scene_toml: str):
        self.dir = Path(directory)
        self.grid_keys = list(grid)
        self.columns = columns(self.grid_keys)
        self.frameworks = identity["frameworks"]
        self.points = {p.key: p for p in points}
        self.csv_path = self.dir / RESULTS
        manifest_path = self.dir / MANIFEST
        make_out_dir(self.dir)
        if manifest_path.exists():
            stored = json.loads(manifest_path.read_text())
            old = {k: stored.get(k) for k in identity}
            if old != identity:
                raise SweepError(f"{self.dir} holds a different sweep ({_describe_difference(old, identity)}); "
                                 "use another --out, or delete that directory to start over")
        else:
            if self.csv_path.exists():
                raise SweepError(f"{self.csv_path} exists but {manifest_path} does not: refusing to mix results; "
                                 "use another --out")
            tmp = manifest_path.with_suffix(".tmp")
            try:
                tmp.write_text(json_output({**identity, **_jsonable(extra), "columns": self.columns,
                                      "created": time.time()}, indent=1))
                os.replace(tmp, manifest_path)
                (self.dir / "scene.toml").write_text(scene_toml)
            except OSError as exc:
                raise SweepError(f"--out {self.dir}: cannot write the sweep's files: {exc.strerror or exc}") from None
        self.done = self._load_done()
        self._fh = None

    def _load_done(self) -> set[str]:
        if not self.csv_path.exists():
            self._rewrite([])
            return set()
        header, rows, clean = read_csv(self.csv_path)
        if header != self.columns:
            raise SweepError(f"{self.csv_path} has columns {header}, expected {self.columns}")
        by_point: dict[str, list[dict]] = {}
        for r in rows:
            by_point.setdefault(r["point"], []).append(r)
        done, keep = set(), []
        for key, rs in by_point.items():
            fws = [r["framework"] for r in rs]
            if key in self.points and sorted(fws) == sorted(self.frameworks):
                done.add(key)
                keep.extend(rs)
            else:
                clean = False        # incomplete (killed between two rows), duplicated or foreign: recompute
        if not clean:
            self._rewrite(keep)
        return done

    def _rewrite(self, rows: list[dict]) -> None:
        tmp = self.csv_path.with_suffix(".tmp")
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=self.columns, lineterminator="\n")
            w.writeheader()
            for r in rows:
                w.writerow(r)
        os.replace(tmp, self.csv_path)

    def pending(self) -> list[Point]:
        return [p for k, p in self.points.items() if k not in self.done]

    def write_point(self, result: dict) -> list[dict]:
        """Append one point's rows (in one write, flushed); returns them as written."""
        key = result["point"]
        if key in self.done:
            return []
        point = self.points[key]
        rows = []
        for r in result["rows"]:
            row = {**dict(point.values), **r}
            row["error"] = " ".join(str(row.get("error", "")).split())   # one line per row, always
            rows.append({c: row.get(c, "") for c in self.columns})
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=self.columns, lineterminator="\n")
        for r in rows:
            w.writerow(r)
        if self._fh is None:
            self._fh = open(self.csv_path, "a", newline="")
        self._fh.write(buf.getvalue())
        self._fh.flush()
        self.done.add(key)
        return rows

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None
