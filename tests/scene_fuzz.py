"""Mutated scene files, and the verdict on each: a clean one-line SceneError naming the key, or a run.

Used by tests/test_scene_fuzz.py (property-based, a sample) and runnable on its own for the whole enumerated set:

    .venv/bin/python tests/scene_fuzz.py            # every mutation of every built-in scene, in-process
    .venv/bin/python tests/scene_fuzz.py --cli 40   # plus 40 of them through the real `flagbot run --json`

A mutation is (what, key, bytes): ``what`` says what was done, ``key`` is the dotted key (or section) the error
message must name when the file is refused (None when any message will do, e.g. for a file that is not TOML).
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from flagbot_sim.scene import SECTIONS, SceneError, load_scene  # noqa: E402
from flagbot_sim.scene_files import builtin_scenes, resolve_scene_path  # noqa: E402

#: the longest error message accepted (the issue saw a 5 MB one echoing a 1e6-element array)
MAX_MESSAGE = 400
HUGE_ARRAY = "[" + ", ".join(["1.0"] * 1_000_000) + "]"       # ~5 MB of TOML
DEEP = 2000                                                   # nesting depth of the deeply nested array

#: replacement values, as TOML text: non-finite, zero, negative, huge and tiny numbers, wrong types, lists
#: where scalars belong, inline tables, very long strings, a huge array and a deeply nested one
VALUES: dict[str, str] = {
    "nan": "nan", "inf": "inf", "-inf": "-inf", "zero": "0", "zero-float": "0.0", "minus-one": "-1",
    "3000": "3000.0", "1e30": "1e30", "-1e30": "-1e30", "1e-30": "1e-30", "1e308": "1.7e308", "int64-max": "9223372036854775807",
    "int64-min": "-9223372036854775808", "true": "true", "string": '"fast"', "empty-string": '""',
    "list-1": "[1]", "list-list-1": "[[1]]", "list-str": '["default"]', "empty-list": "[]",
    "table": "{ a = 1 }", "long-string": '"' + "x" * 200_000 + '"', "date": "1979-05-27T07:32:00Z",
    "huge-array": HUGE_ARRAY, "deep-array": "[" * DEEP + "1" + "]" * DEEP,
    "big-list": "[" + ", ".join(["0.0"] * 500) + "]",
}
#: values too large to try at every key (each costs a 5 MB file); tried at a few keys only
BIG_VALUES = {"huge-array", "deep-array"}
BIG_VALUE_KEYS = {"gravity.g", "scene.effects", "flagellum.length", "scene.preset", "robot.n_flagella"}


def toml_text(data: dict) -> str:
    """A scene dict back to TOML (values as they were read: str, bool, int, float, list, dict)."""
    lines = []
    for section, values in data.items():
        lines.append(f"[{section}]")
        for k, v in values.items():
            lines.append(f"{k} = {_value(v)}")
        lines.append("")
    return "\n".join(lines)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_string(k)} = {_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(type(v))


def _string(v: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters (incl. DEL) escaped."""
    return '"' + "".join(f"\\u{ord(c):04x}" if ord(c) < 32 or ord(c) == 127 or c in '"\\' else c for c in v) + '"'


def with_raw(data: dict, section: str, key: str, raw: str) -> bytes:
    """The scene's TOML with ``section.key = raw`` (raw TOML text), the key added if it was not there."""
    out = []
    sections = dict(data)
    sections.setdefault(section, {})
    for s, values in sections.items():
        out.append(f"[{s}]")
        for k, v in values.items():
            if (s, k) != (section, key):
                out.append(f"{k} = {_value(v)}")
        if s == section:
            out.append(f"{key} = {raw}")
        out.append("")
    return "\n".join(out).encode()


def base_scenes() -> dict[str, dict]:
    return {name: tomllib.loads(resolve_scene_path(name).read_text()) for name in builtin_scenes()}


def declared_keys() -> list[tuple[str, str]]:
    import dataclasses
    return [(s, f.name) for s, cls in SECTIONS.items() for f in dataclasses.fields(cls)]


def mutations(values: dict[str, str] = VALUES):
    """Every enumerated mutation of every built-in scene: (name, what, key, bytes)."""
    for name, data in base_scenes().items():
        text = toml_text(data).encode()
        yield name, "unchanged", None, text
        # whole-file damage
        yield name, "empty file", None, b""
        yield name, "only comments", None, b"# a scene\n\n   # nothing else\n"
        yield name, "truncated", None, text[: len(text) // 2]
        yield name, "non-UTF-8 byte in a comment", None, text + b"\n# caf\xe9\n"
        yield name, "non-UTF-8 bytes in a string", None, text.replace(b"[scene]",
                                                                    b"[scene]\ndescription = \"\xff\xfe\"", 1)
        yield name, "UTF-16 file", None, toml_text(data).encode("utf-16")
        yield name, "binary garbage", None, bytes(range(256)) * 4
        yield name, "NUL bytes", None, text.replace(b"\n", b"\x00\n", 3)
        yield name, "unknown section", "nosuch", text + b"\n[nosuch]\na = 1\n"
        no_robot = toml_text({s: v for s, v in data.items() if s != "robot"})
        yield name, "section as a value", "robot", ("robot = 5\n" + no_robot).encode()
        yield name, "deeply nested tables", None, (".".join(["a"] * DEEP) + " = 1\n").encode()
        yield name, "very long key", None, text + ("\n[robot]\n" + "k" * 100_000 + " = 1\n").encode()
        for section in data:
            rest = {s: v for s, v in data.items() if s != section}
            yield name, f"deleted section [{section}]", section, toml_text(rest).encode()
            yield name, f"unknown key in [{section}]", f"{section}.nosuch", with_raw(data, section, "nosuch", "1")
            for key in data[section]:
                values_left = {k: v for k, v in data[section].items() if k != key}
                yield name, f"deleted {section}.{key}", f"{section}.{key}", toml_text({**data, section: values_left}).encode()
        for section, key in declared_keys():
            for label, raw in values.items():
                if label in BIG_VALUES and f"{section}.{key}" not in BIG_VALUE_KEYS:
                    continue
                # a file above the size limit is refused unread: no key to name
                yield name, f"{section}.{key} = <{label}>", None if label == "huge-array" else f"{section}.{key}", \
                    with_raw(data, section, key, raw)


# ---------------------------------------------------------------- verdicts

class Bad(AssertionError):
    """A mutation that was neither refused cleanly nor run cleanly."""


def check_message(msg: str, key) -> None:
    """One line, at most MAX_MESSAGE characters, naming ``key`` (a dotted key, a section, or a list of either:
    any one of them; None: no key to name)."""
    if "\n" in msg:
        raise Bad(f"multi-line error message: {msg[:300]!r}")
    if len(msg) > MAX_MESSAGE:
        raise Bad(f"error message of {len(msg)} characters: {msg[:200]!r}...")
    if key is None:
        return
    keys = [key] if isinstance(key, str) else list(key)
    if not any(k in msg for k in keys):
        raise Bad(f"error message names none of {keys}: {msg!r}")


def strict_json(out: dict) -> dict:
    """``out`` through the CLI's JSON writer and back through a strict parser; no non-finite number survives."""
    from flagbot_sim.cliutil import dumps

    def refuse(token):
        raise Bad(f"non-finite number {token} in the JSON")
    return json.loads(dumps(out), parse_constant=refuse)


def run_in_process(path: Path, key: str | None, steps: int = 3) -> str:
    """'refused' or 'ran' (or 'step failed': Newton gave up, reported cleanly); raises Bad otherwise."""
    from flagbot_sim.physics import Simulation, StepFailed
    try:
        scene = load_scene(path)
    except SceneError as exc:
        check_message(str(exc), key)
        return "refused"
    except Exception as exc:                                      # noqa: BLE001 - the point of the test
        raise Bad(f"load_scene raised {type(exc).__name__}: {str(exc)[:200]}") from exc
    try:
        sim = Simulation(scene)
        verdict = "ran"
        try:
            for _ in range(steps):
                sim.step()
        except StepFailed:
            verdict = "step failed"
        strict_json(sim.summary())
        return verdict
    except Bad:
        raise
    except Exception as exc:                                      # noqa: BLE001
        raise Bad(f"the simulation raised {type(exc).__name__}: {str(exc)[:200]}") from exc


def run_cli(path: Path, key: str | None, timeout: float = 120.0) -> str:
    """The same through ``python -m flagbot_sim run PATH --duration 0.05 --json``, as users run it.
    The verdict; the finished process is left in ``run_cli.last``."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.run([sys.executable, "-m", "flagbot_sim", "run", str(path), "--duration", "0.05", "--json"],
                       capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout)
    run_cli.last = p
    if "Traceback" in p.stderr:
        raise Bad(f"traceback: {p.stderr[-600:]}")
    if p.returncode == 2:
        err = p.stderr.strip()
        if not err.startswith("error: "):
            raise Bad(f"exit 2 without an 'error:' line: {err[:300]!r}")
        check_message(err, key)
        return "refused"
    if p.returncode not in (0, 1):
        raise Bad(f"exit {p.returncode}: {p.stderr[-300:]!r}")

    def refuse(token):
        raise Bad(f"non-finite number {token} in the JSON")
    out = json.loads(p.stdout, parse_constant=refuse)
    if p.returncode == 1 and "error" not in out:
        raise Bad("exit 1 without an error in the JSON")
    return "ran" if p.returncode == 0 else "step failed"


def main(argv: list[str]) -> int:
    import argparse
    import random
    import tempfile
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cli", type=int, default=0, metavar="K", help="also run K random mutations through the CLI")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    counts: dict[str, int] = {}
    bad: list[tuple[str, str, str]] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mutated.toml"
        cases = list(mutations())
        for name, what, key, data in cases:
            path.write_bytes(data)
            t = time.perf_counter()
            try:
                verdict = run_in_process(path, key)
            except Bad as exc:
                verdict = "BAD"
                bad.append((name, what, str(exc)))
            if time.perf_counter() - t > 10:
                bad.append((name, what, f"took {time.perf_counter() - t:.1f} s"))
            counts[verdict] = counts.get(verdict, 0) + 1
        print(f"in-process: {len(cases)} mutated files in {time.perf_counter() - t0:.1f} s: "
              + ", ".join(f"{v} {k}" for k, v in sorted(counts.items())))
        if args.cli:
            rng = random.Random(args.seed)
            sample = rng.sample(cases, min(args.cli, len(cases)))
            cli_counts: dict[str, int] = {}
            for name, what, key, data in sample:
                path.write_bytes(data)
                try:
                    verdict = run_cli(path, key)
                except (Bad, subprocess.TimeoutExpired) as exc:
                    verdict = "BAD"
                    bad.append((name, what, "CLI: " + str(exc)[:300]))
                cli_counts[verdict] = cli_counts.get(verdict, 0) + 1
            print(f"CLI: {len(sample)} mutated files: " + ", ".join(f"{v} {k}" for k, v in sorted(cli_counts.items())))
    for name, what, why in bad:
        print(f"BAD {name}: {what}: {why}")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
