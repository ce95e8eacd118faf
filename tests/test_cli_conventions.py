"""The command-line conventions every program of the package keeps (docs/cli.md): ``--version``, a ``version`` in
every JSON output, one exit code for a missing extra, and what ``--view-wait`` says it waits for."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import flagbot_sim
from flagbot_sim import cli, optional
from cli_helpers import ROOT

VERSION = flagbot_sim.__version__
SCRIPTS = ("flagbot", "sim_node", "beam_node", "cmd_profile", "record", "replay")
BAG = ROOT / "bags" / "design2_n2_steps.mcap"


def strict(text: str):
    return json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))


# ------------------------------------------------------------------------------------------------ --version
@pytest.mark.parametrize("prog", SCRIPTS)
def test_every_console_script_prints_the_package_version(prog):
    script = Path(sys.executable).with_name(prog)          # the installed console script, as a user runs it
    p = subprocess.run([str(script), "--version"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout == f"{prog} (flagbot_sim) {VERSION}\n" and p.stderr == ""
    if prog != "flagbot":
        # the ROS processes answer it from their own arguments, after a --ros-args ... -- section too
        p = subprocess.run([str(script), "--ros-args", "-p", "scene:=design2", "--", "--version"],
                           capture_output=True, text=True, timeout=120)
        assert p.returncode == 0 and p.stdout == f"{prog} (flagbot_sim) {VERSION}\n", p.stderr


@pytest.mark.parametrize("prog", ["sim_node", "cmd_profile"])
def test_version_needs_no_ros(prog, tmp_path):
    """``--version`` is answered before ROS 2 is imported: it works where rclpy cannot be."""
    code = (f"import sys; sys.modules['rclpy'] = None; sys.argv = ['{prog}', '--version']; "
            f"from flagbot_sim.console import {prog}; sys.exit({prog}())")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert p.returncode == 0 and p.stdout == f"{prog} (flagbot_sim) {VERSION}\n", p.stderr


def test_a_version_inside_the_ros_arguments_is_not_the_programs_own():
    from flagbot_sim.console import own_arguments
    assert own_arguments(["--ros-args", "-r", "--version", "--", "x"]) == ["x"]
    assert own_arguments(["a", "--ros-args", "-p", "n:=1"]) == ["a"]
    assert own_arguments(["--version", "--ros-args", "-p", "n:=1", "--", "b"]) == ["--version", "b"]


# ------------------------------------------------------------------------------------------------ JSON
def test_every_json_result_printed_carries_the_version(capsys, tmp_path):
    """run, steady, beam (a list: each object), bag-summary, replay --resimulate: ``version`` first, strict JSON."""
    cases = [(["run", "design2", "--duration", "0.05", "--json"], 0),
             (["steady", "design2", "--omega-rpm", "50", "--no-stability", "--json"], 0),
             (["beam", "design2", "--omega-rpm", "50,100", "--json"], 0),
             (["bag-summary", str(BAG), "--json"], 0),
             (["replay", str(BAG), "--resimulate", "--json"], 0)]
    for argv, code in cases:
        assert cli.main(argv) == code, argv
        out = strict(capsys.readouterr().out)
        objects = out if isinstance(out, list) else [out]
        assert isinstance(out, list) == (argv[0] == "beam")         # a list stays a list
        assert len(objects) == (2 if argv[0] == "beam" else 1)
        for obj in objects:
            assert list(obj)[0] == "version" and obj["version"] == VERSION, argv


def test_a_sweeps_json_files_carry_the_version(tmp_path, capsys):
    out = tmp_path / "sweep"
    assert cli.main(["sweep", "design2", "--grid", "rpm=40,60", "--method", "steady", "--frameworks", "der,lb",
                     "--quiet", "--out", str(out)]) == 0
    for name in ("sweep.json", "summary.json"):
        assert strict((out / name).read_text())["version"] == VERSION, name
    capsys.readouterr()
    # and a resumed sweep (same identity) still matches the manifest written with the version in it
    assert cli.main(["sweep", "design2", "--grid", "rpm=40,60", "--method", "steady", "--frameworks", "der,lb",
                     "--quiet", "--no-plot", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "; 2 already in " in err and "computing 0 " in err, err


#: JSON the package prints or writes that is not a command's result for its user, with the reason
NOT_RESULTS = {
    "flagbot_sim/bench/startup.py": "the timed child process's report to its parent",
    "flagbot_sim/bench/flood.py": "the flooding child process's report to its parent",
    "flagbot_sim/bench/accuracy.py": "references.json, the reference cache keyed by case (re-read as such)",
}


def test_no_module_prints_or_writes_json_without_the_version():
    """Every ``print(...dumps(`` / ``write_text(...dumps(`` goes through cliutil.json_output (the one place that
    adds the version), except the files that are not results (NOT_RESULTS, each with its reason)."""
    pattern = re.compile(r"(print|write_text)\(\s*(json\.)?dumps\(")
    offenders, excepted = [], set()
    for path in sorted((ROOT / "flagbot_sim").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        for k, line in enumerate(path.read_text().splitlines(), 1):
            if pattern.search(line):
                if rel in NOT_RESULTS:
                    excepted.add(rel)
                else:
                    offenders.append(f"{rel}:{k}: {line.strip()}")
    assert offenders == [], "JSON output without the version (use cliutil.json_output):\n" + "\n".join(offenders)
    assert excepted == set(NOT_RESULTS), "a NOT_RESULTS entry no longer writes JSON: remove it"


def test_json_output_adds_the_version_first_and_keeps_lists_lists():
    from flagbot_sim.cliutil import json_output
    assert strict(json_output({"a": 1, "version": "stale"})) == {"version": VERSION, "a": 1}
    assert strict(json_output([{"a": float("nan")}, 3])) == [{"version": VERSION, "a": None}, 3]


# ------------------------------------------------------------------------------------------------ missing extras
def _without(module: str, argv: list[str], cwd) -> subprocess.CompletedProcess:
    """``flagbot ARGV`` in a process where ``module`` cannot be imported (None in sys.modules: Python's own way
    to make an import fail as if the module were not installed)."""
    code = (f"import sys; sys.modules[{module!r}] = None; from flagbot_sim.cli import main; "
            f"sys.exit(main({argv!r}))")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=cwd,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))


@pytest.mark.parametrize("extra, module, argv", [
    ("dask", "distributed", ["sweep", "design2", "--grid", "rpm=40", "--engine", "dask", "--quiet", "--out", "s"]),
    ("dask", "distributed", ["optimize", "design2", "--vary", "n=2:3", "--engine", "dask", "--quiet", "--out", "o"]),
    ("view", "foxglove", ["run", "design2", "--duration", "0.01", "--view"]),
    ("view", "foxglove", ["replay", str(BAG), "--view"]),
    ("ros", "rclpy", ["record", "-o", "x.mcap"]),
])
def test_every_missing_extra_exits_with_the_one_code(extra, module, argv, tmp_path):
    p = _without(module, argv, tmp_path)
    assert p.returncode == optional.EXIT_CODE == 2, p.stderr
    assert p.stdout == "" and p.stderr.count("\n") == 1, p.stderr
    assert p.stderr.startswith("error: ") and p.stderr.rstrip().endswith(f"pip install 'flagbot_sim[{extra}]'")


def test_a_ros_console_script_without_ros_exits_with_the_same_code(tmp_path):
    code = "import sys; sys.modules['rclpy'] = None; from flagbot_sim.console import replay; sys.exit(replay())"
    p = subprocess.run([sys.executable, "-c", code, str(BAG)], capture_output=True, text=True, timeout=120,
                       cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert p.returncode == optional.EXIT_CODE and p.stderr.startswith("error: replay needs ROS 2 Jazzy"), p.stderr


# ------------------------------------------------------------------------------------------------ --view-wait
def test_view_wait_counts_a_subscriber_not_a_connection(capsys):
    """A client that is connected but subscribed to nothing is not what --view-wait waits for, and the note says
    what it waited for; once the client subscribes, the wait ends."""
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    import asyncio

    from foxglove_client import Client
    from flagbot_sim.view.cli import wait_or_note
    from flagbot_sim.view.live import TOPICS, LiveView
    view = LiveView(port=0)
    loop = asyncio.new_event_loop()
    try:
        client = loop.run_until_complete(Client.connect(view.url))       # connected: serverInfo, advertise
        assert set(client.topics()) == set(TOPICS)
        assert wait_or_note(view, 0.5, "running") is False
        note = capsys.readouterr().err
        assert note.startswith("live view: no client subscribed to /flagbot/scene, ") and "within 0.5 s" in note
        assert note.rstrip().endswith("running anyway") and "no client after" not in note
        loop.run_until_complete(client.subscribe({"/flagbot/state"}))
        assert wait_or_note(view, 20.0, "running") is True
        assert capsys.readouterr().err == ""
        loop.run_until_complete(client.ws.close())
    finally:
        view.close(linger=0)
        loop.close()
