"""Scene input never raises a traceback: every mutated scene is refused with one short line naming the key, or it
runs (a few steps, a summary that strict JSON parsers accept). The mutations and verdicts are in scene_fuzz.py;
``python tests/scene_fuzz.py --cli 40`` runs the whole enumerated set plus 40 through the real CLI."""
import json
import math
import tempfile
import time
from pathlib import Path

import pytest
import scene_fuzz as F
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from conftest import FUZZ_EXAMPLES

from flagbot_sim.scene import SceneError, load_scene
from flagbot_sim.scene_files import resolve_scene_path

BASES = F.base_scenes()
KEYS = F.declared_keys()


def test_every_enumerated_mutation_is_refused_in_one_line_or_runs(tmp_path):
    """~2100 files: each declared key of each built-in scene set to non-finite, zero, negative, huge, tiny, wrong
    types, lists for scalars ([1], [[1]]), tables, 200 000-character strings, a 5 MB array, 2000-deep nesting;
    deleted keys and sections, unknown ones; empty, comment-only, truncated, non-UTF-8, UTF-16 and binary files."""
    path = tmp_path / "mutated.toml"
    verdicts, bad = {}, []
    for name, what, key, data in F.mutations():
        path.write_bytes(data)
        t0 = time.perf_counter()
        try:
            verdict = F.run_in_process(path, key)
        except F.Bad as exc:
            bad.append(f"{name}: {what}: {exc}")
            continue
        if time.perf_counter() - t0 > 20:
            bad.append(f"{name}: {what}: took {time.perf_counter() - t0:.0f} s")
        verdicts[verdict] = verdicts.get(verdict, 0) + 1
    assert not bad, f"{len(bad)} bad verdicts:\n" + "\n".join(bad[:30])
    # the set is not trivially refused wholesale: the unchanged and the harmlessly changed scenes still run
    assert verdicts.get("ran", 0) >= 3 * 20 and verdicts["refused"] > 1000, verdicts


# ---------------------------------------------------------------- property-based: several changes at once

SPECIAL = [0, 0.0, -1, -0.0, 1e30, -1e30, 1e-30, 1.7e308, 5e-324, 2 ** 63 - 1, -2 ** 63, math.nan, math.inf,
           -math.inf, True, "", "x" * 5000, [1], [[1]], [], ["default"], {"a": 1}]
TEXT = st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=40)
SCALARS = st.one_of(st.floats(), st.integers(min_value=-2 ** 63, max_value=2 ** 63 - 1), st.booleans(), TEXT)
VALUES = st.one_of(
    st.sampled_from(SPECIAL),
    SCALARS,
    st.lists(SCALARS, max_size=6),
    st.lists(st.lists(st.integers(-3, 3), max_size=3), max_size=3),
    st.dictionaries(st.text("abcxyz", min_size=1, max_size=4), st.integers(), max_size=2),
    st.sampled_from(["inertia", "rft", "clamp", "motor", "gravity", "fast", "accurate", "splu"]),
)


@st.composite
def mutated_scene(draw):
    """(bytes, touched keys): a built-in scene with 1-4 keys deleted, rescaled by 10^k, set to anything, or added."""
    name = draw(st.sampled_from(sorted(BASES)))
    data = {s: dict(v) for s, v in BASES[name].items()}
    touched = []
    for _ in range(draw(st.integers(1, 4))):
        section, key = draw(st.sampled_from(KEYS))
        kind = draw(st.sampled_from(["delete", "scale", "scale", "set", "set", "unknown"]))
        touched.append(f"{section}.{key}")
        values = data.setdefault(section, {})
        if kind == "delete":
            values.pop(key, None)
        elif kind == "scale":
            # the most searching mutation: a plausible value off by orders of magnitude (tiny edges, huge heads)
            from flagbot_sim.scene import SECTIONS
            default = values.get(key, SECTIONS[section].__dataclass_fields__[key].default)
            if isinstance(default, (int, float)) and not isinstance(default, bool):
                values[key] = float(default or 1.0) * 10.0 ** draw(st.integers(-9, 9)) * draw(
                    st.sampled_from([1, -1, 0.5, 3]))
            else:
                values[key] = draw(VALUES)
        elif kind == "set":
            values[key] = draw(VALUES)
        else:
            unknown = draw(st.text("abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=12))
            values[unknown] = draw(VALUES)
            touched.append(f"{section}.{unknown}")
    return F.toml_text(data).encode(), touched + sorted({k.split(".")[0] for k in touched})


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=mutated_scene())
def test_random_combined_mutations_are_refused_in_one_line_or_run(case):
    data, touched = case
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.toml"
        path.write_bytes(data)
        t0 = time.perf_counter()
        F.run_in_process(path, touched)
        assert time.perf_counter() - t0 < 30, "a mutated scene took more than 30 s to refuse or run 3 steps"


# ---------------------------------------------------------------- the override path (CLI --set, ROS scene_overrides)

@settings(max_examples=FUZZ_EXAMPLES, deadline=None, database=None)
@given(key=st.sampled_from(KEYS), value=VALUES)
def test_override_values_of_any_type_are_refused_in_one_line_or_accepted(key, value):
    dotted = f"{key[0]}.{key[1]}"
    try:
        load_scene("design1", {dotted: value})
    except SceneError as exc:
        F.check_message(str(exc), dotted)


@pytest.mark.parametrize("value, words", [
    (list(range(1_000_000)), ["gravity.g", "1000000 items"]),
    ([0.0, 0.0, 1e30], ["gravity.g", "1e+30", "<= 10000"]),
    ("x" * 1_000_000, ["gravity.g", "1000000 characters"]),
])
def test_huge_values_are_not_echoed_back(value, words):
    with pytest.raises(SceneError) as exc:
        load_scene("design1", {"gravity.g": value})
    msg = str(exc.value)
    assert len(msg) < 300 and all(w in msg for w in words), msg


def test_deep_nesting_and_odd_override_strings_are_refused_cleanly():
    deep = [1]
    for _ in range(100_000):              # far deeper than any recursion limit
        deep = [deep]
    with pytest.raises(SceneError, match="scene.effects") as exc:
        load_scene("design1", {"scene.effects": deep})
    assert len(str(exc.value)) < 300
    with pytest.raises(SceneError, match="gravity.g"):
        load_scene("design1", ["gravity.g=" + "[" * 5000 + "]" * 5000])
    for bad in (["scene.preset=[1]"], ["scene.effects=[[1]]"], ["scene.preset={a=1}"]):
        with pytest.raises(SceneError, match=bad[0].split("=")[0]):
            load_scene("design1", bad)


def test_scene_paths_that_are_not_regular_files_are_refused(tmp_path):
    import os
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)                       # reading a FIFO would block forever
    for target, words in ((fifo, "not a regular file"), (tmp_path, "directory"), ("", "empty"),
                          ("a\0b", "holds a NUL (U+0000)"), ("x" * 5000 + ".toml", "cannot be read")):
        with pytest.raises(SceneError) as exc:
            resolve_scene_path(target)
        assert words in str(exc.value) and len(str(exc.value)) < 300, str(exc.value)


# ---------------------------------------------------------------- the real CLI, as users run it

CLI_CASES = {
    "empty file": (b"", None, "sets no keys"),
    "only comments": (b"# nothing here\n\n[scene]\n", None, "sets no keys"),
    "non-UTF-8": (F.toml_text(BASES["design1"]).encode() + b"\n# caf\xe9\n", None, "not UTF-8"),
    "preset = [1]": (F.with_raw(BASES["design1"], "scene", "preset", "[1]"), "scene.preset", "scene.preset"),
    "effects = [[1]]": (F.with_raw(BASES["design2"], "scene", "effects", "[[1]]"), "scene.effects", "effects"),
    "head radius 1e30": (F.with_raw(BASES["design1"], "head", "radius", "1e30"), "head.radius", "head.radius"),
    "deep array": (F.with_raw(BASES["design1"], "gravity", "g", "[" * 3000 + "]" * 3000), "gravity.g", "deeply"),
    "runs": (F.with_raw(BASES["design2"], "head", "C1", "0"), None, None),
}


@pytest.mark.parametrize("case", list(CLI_CASES))
def test_cli_run_json_on_mutated_scenes(case, tmp_path):
    data, key, needle = CLI_CASES[case]
    path = tmp_path / "scene.toml"
    path.write_bytes(data)
    verdict = F.run_cli(path, key)
    if needle is None:
        assert verdict == "ran"
    else:
        assert verdict == "refused"
        p = F.run_cli.last
        assert needle in p.stderr and p.stdout == "" and p.stderr.count("\n") == 1, p.stderr


def test_strict_json_has_no_infinity_even_before_any_step():
    from flagbot_sim.cliutil import dumps
    from flagbot_sim.physics import Simulation
    out = Simulation(load_scene("design1")).summary()         # no step taken: no wall time, no rates
    parsed = json.loads(dumps(out), parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    assert parsed["real_time_factor"] is None and parsed["steps"] == 0
