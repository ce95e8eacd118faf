"""The command line, run as users run it: a separate process."""
import json
import re
import time

import pytest
from cli_helpers import flagbot


def test_run_json_reports_the_documented_keys():
    t0 = time.perf_counter()
    p = flagbot("run", "design2", "--duration", "0.3", "--set", "flagellum.length=0.05", "--json")
    process_wall = time.perf_counter() - t0
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    for key in ("omega_T", "omega_h", "omega_t", "v", "steps", "newton_iterations", "wall_seconds",
                "real_time_factor", "startup_seconds"):
        assert key in out
    # start-up (process start to simulation ready) is part of the process's wall time, not of the stepping's
    assert 0.0 < out["startup_seconds"] < process_wall
    assert out["steps"] == 30 and out["omega_T"] == pytest.approx(100 * 2 * 3.141592653589793 / 60)
    # no progress bar in JSON mode: stderr holds at most the compile report of a cold kernel cache (a fresh
    # clone's first run: the notice, one line per kernel group compiled, the total), which tells the user why
    # this run is slow; stdout is the JSON alone (parsed above)
    compile_report = ("flagbot_sim: compiling kernels", "flagbot_sim:   ", "flagbot_sim: kernels compiled in")
    lines = [ln for ln in p.stderr.splitlines() if not ln.startswith(compile_report)]
    assert lines == [] and "\r" not in p.stderr


def test_clamped_run_reports_force_torque_and_tip():
    p = flagbot("run", "clamped_flagellum", "--duration", "0.2", "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    # the medium resists the rotation at every instant (Fx changes sign during start-up: while the rod bends,
    # its segments slide towards the base and tangential drag pushes them away; at steady state it is thrust)
    assert out["Tx"] < 0 and len(out["tip"]) == 3 and isinstance(out["Fx"], float)
    # the tip starts near (L, R_d, 0) in the co-rotating frame
    assert out["tip"][0] == pytest.approx(0.111, abs=5e-3) and out["tip"][1] == pytest.approx(0.02, abs=5e-3)


def test_human_readable_run_shows_progress_and_summary():
    p = flagbot("run", "design1", "--duration", "0.1", "--set", "flagellum.length=0.05")
    assert p.returncode == 0
    assert "omega_h" in p.stdout and "real-time factor" in p.stdout and "nan" not in p.stdout
    # stderr is a pipe here, as in a log file: plain progress lines, no carriage-return redraws, no nan
    lines = p.stderr.splitlines()
    assert lines and all("%" in ln for ln in lines) and "100.0%" in lines[-1]
    assert "\r" not in p.stderr and "nan" not in p.stderr


def test_progress_redraws_in_place_within_the_terminal_width_on_a_tty():
    """The path a person at a terminal takes: stderr is a pseudo-terminal 50 columns wide."""
    import fcntl
    import os
    import pty
    import struct
    import subprocess
    import sys
    import termios
    from cli_helpers import ROOT
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 50, 0, 0))
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    env["PYTHONPATH"] = str(ROOT)
    proc = subprocess.Popen([sys.executable, "-m", "flagbot_sim", "run", "design2", "--duration", "1.5",
                             "--set", "flagellum.length=0.05"], stdout=subprocess.PIPE, stderr=slave, cwd=ROOT,
                            env=env)
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 4096)
        except OSError:                   # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(master)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0
    tty = b"".join(chunks).decode()
    draws = tty.replace("\r\n", "\n").split("\r")
    assert len(draws) >= 2, tty                      # redrawn in place, not one line per update
    for d in draws:
        for line in d.split("\n"):
            assert len(line) <= 49, line             # one column short of the edge: never wraps
    assert "nan" not in tty and tty.rstrip().endswith(tty.rstrip().split("\r")[-1])
    assert b"omega_h" in out


def test_bad_input_is_a_one_line_error_naming_the_key():
    p = flagbot("run", "design1", "--set", "flagellum.youngs_modulus=-5")
    assert p.returncode == 2
    assert p.stderr.strip().startswith("error: flagellum.youngs_modulus")
    assert "Traceback" not in p.stderr


def test_run_imports_neither_ros_nor_plotting_nor_the_beam_optimiser():
    """`flagbot run` starts fast: the parser imports only the command being run, and run needs no rclpy,
    matplotlib, scipy.optimize (the beam estimator's) or dask."""
    import subprocess
    import sys
    from cli_helpers import ROOT
    code = ("import sys; from flagbot_sim.cli import main; code = main(['run', 'design1', '--duration', '0.05', "
            "'--quiet']); heavy = ('rclpy', 'matplotlib', 'scipy.optimize', 'scipy.integrate', 'dask', "
            "'flagbot_sim.beam', 'flagbot_sim.bag', 'flagbot_sim.sweep'); "
            "print([m for m in heavy if m in sys.modules]); sys.exit(code)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                       env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip().splitlines()[-1] == "[]"


def test_help_lists_every_command_without_importing_them(capsys):
    import sys
    from flagbot_sim import cli
    from flagbot_sim.commands import compile, completion, run, scenes  # noqa: F401 -- always listed, always imported
    before = set(sys.modules)
    parser = cli.build_parser(None)
    assert not {m for m in set(sys.modules) - before if m.startswith(("flagbot_sim.", "scipy", "matplotlib"))}
    text = parser.format_help()
    for command in ("run", "scenes", *cli.COMMANDS):
        assert command in text


def test_the_lazy_command_table_names_what_the_modules_register():
    """cli.COMMANDS (shown by --help without importing anything) must list exactly the commands each module
    adds; a command added to a module but not to the table would be missing from --help."""
    import argparse
    import importlib
    from flagbot_sim import cli
    for module in cli.COMMAND_MODULES:
        sub = argparse.ArgumentParser().add_subparsers()
        importlib.import_module(module).register(sub)
        listed = {c for c, (m, _) in cli.COMMANDS.items() if m == module}
        assert set(sub.choices) == listed, f"{module} registers {sorted(sub.choices)}, cli.COMMANDS lists " \
                                           f"{sorted(listed)}"
    # and each command's parser is the module's real one when that command is run
    assert "--omega-rpm" in cli.build_parser("beam")._subparsers._group_actions[0].choices["beam"].format_help()


def test_scenes_prints_aligned_columns(capsys):
    from flagbot_sim.cli import main
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    rows = out.split("\nkeys:\n")[1].splitlines()
    header = rows[0]
    starts = [header.index(w) for w in ("key", "default", "unit", "allowed", "meaning")]
    assert len(rows) > 25
    for r in rows:
        for a in starts[1:]:
            # every column starts at the header's offset: two spaces before it, text at it
            assert r[a - 2:a] == "  " and r[a] != " ", (r, a)
    effects = out.split("effects:\n")[1].split("\n\n")[0].splitlines()
    assert len({len(ln) - len(ln.strip().split(" ", 1)[1].lstrip()) for ln in effects}) == 1


def test_summary_shows_missing_values_as_dashes_never_nan():
    from flagbot_sim.commands.run import format_summary
    from flagbot_sim.scene import load_scene
    out = {"scene": "design1", "n_flagella": 2, "omega_T": 10.47, "omega_h": None, "omega_t": float("nan"),
           "v": None, "steady": False, "window": 2.0, "time": 0.0, "steps": 0, "newton_iterations": 0,
           "dt_reductions": 0, "wall_seconds": 0.0, "real_time_factor": None}
    text = format_summary(load_scene("design1"), out)
    assert "nan" not in text.lower() and "real-time factor --" in text and "omega_h = -- rad/s" in text
    clamped = {**out, "scene": "clamped_flagellum", "Fx": None, "Tx": float("inf"), "tip": [0.1, None, 0.0]}
    text = format_summary(load_scene("clamped_flagellum"), clamped)
    assert "inf" not in text and "nan" not in text and "Fx  (axial force on the flagellum)  = -- N" in text


def test_bench_startup_times_whole_processes():
    p = flagbot("bench", "startup", "--no-cold", "--repeat", "2", "--scene", "design2")
    assert p.returncode == 0, p.stderr
    rows = {ln.split("  ")[1].strip(): ln for ln in p.stdout.splitlines() if ln.startswith("  ") and "(" in ln}
    warm = rows["warm: --duration 0.1, kernel cache filled"]
    med, lo, hi = (float(x) for x in re.findall(r"\d+\.\d+", warm)[-3:])
    assert 0.0 < lo <= med <= hi < 120.0
    imp = rows['import: python -c "import numpy, scipy.sparse, numba"']
    ratio = rows["warm / import"]
    r_med, r_lo, r_hi = (float(x) for x in re.findall(r"\d+\.\d+", ratio.split("target")[0])[-3:])
    # a ratio of whole processes: warm flagbot does everything the import line does and more
    assert 1.0 < r_lo <= r_med <= r_hi and "target <= 2" in ratio
    assert "cold / warm" not in p.stdout and "load average" in p.stdout and imp


def test_only_the_command_line_process_skips_its_final_collection():
    """main() called in-process (as here) leaves the garbage collector alone; the console script's process,
    which ends right after, freezes it so that shutdown does not walk every object (0.4 s of a warm run)."""
    import gc
    from flagbot_sim.cli import main
    frozen = gc.get_freeze_count()          # (a cold kernel compile earlier in this process freezes its objects)
    assert main(["scenes"]) == 0 and gc.get_freeze_count() == frozen


def test_a_reader_that_goes_away_is_no_traceback():
    """`flagbot scenes | head -1` and `sim_node --help | head -1`: the reader closes the pipe early; the writer
    stops quietly (it printed a BrokenPipeError traceback), with stdout unbuffered or block-buffered (a user's
    shell: no PYTHONUNBUFFERED, so the broken pipe shows only at the last flush)."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    bindir = Path(sys.executable).parent
    for unbuffered in (True, False):
        env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
        if unbuffered:
            env["PYTHONUNBUFFERED"] = "1"
        for cmd in (f"'{bindir / 'flagbot'}' scenes", f"'{bindir / 'sim_node'}' --help"):
            p = subprocess.run(f"{cmd} | head -c 10 > /dev/null", shell=True, capture_output=True, text=True,
                               timeout=60, env=env)
            assert "Traceback" not in p.stderr and "BrokenPipe" not in p.stderr, (cmd, unbuffered, p.stderr)


def test_a_duration_shorter_than_a_step_is_refused_not_rounded_up():
    """`--duration 1e-6` ran a whole 0.01 s step and reported time 0.01 without a word."""
    p = flagbot("run", "design1", "--duration", "1e-6", "--json")
    assert p.returncode == 2 and p.stdout == "" and "shorter than half a time step" in p.stderr


def test_an_out_directory_that_is_a_file_is_refused_before_any_work(tmp_path):
    """sweep, fit and optimize ended with a FileExistsError traceback after all their work; now one line, exit 2,
    and the file is left as it was."""
    taken = tmp_path / "taken"
    taken.write_text("keep me")
    data = tmp_path / "data.csv"
    data.write_text("n,omega_T_rpm,v\n2,100,0.0002\n2,150,0.0003\n")
    for argv in (["sweep", "design1", "--grid", "n=2", "--out", str(taken)],
                 ["fit", "design1", str(data), "--fit", "medium.mu", "--out", str(taken), "--quiet"],
                 ["optimize", "design1", "--vary", "omega_rpm=20:100", "--out", str(taken)]):
        p = flagbot(*argv)
        assert p.returncode == 2 and "Traceback" not in p.stderr, (argv, p.stderr)
        assert p.stderr == f"error: --out {taken}: exists and is not a directory\n", p.stderr
    assert taken.read_text() == "keep me"
