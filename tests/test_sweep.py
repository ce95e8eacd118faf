"""`flagbot sweep`: grid parsing and validation, engines that agree to the last bit, steady-state detection with a
cap, resume after a kill, and a sweep directory that refuses to mix two different sweeps."""
import csv
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from flagbot_sim.cli import main
from flagbot_sim.physics import Simulation
from flagbot_sim.scene import load_scene
from flagbot_sim.sweep import SteadySettings, SweepError, parse_grid
from flagbot_sim.sweep.engines import run_tasks
from flagbot_sim.sweep.store import RESULTS, read_results
from flagbot_sim.sweep.task import make_task, run_der

ROOT = Path(__file__).resolve().parents[1]
# design 2 with a 50 mm flagellum: eta_p L^4/EI ~ 0.3 s, steady within ~3 s of simulated time, ~0.2 s per point
# time-stepped (the engines, the detection, resuming are about that path; the steady method has its own tests)
SMALL = ["design2", "--set", "flagellum.length=0.05", "--grid", "n=2,3", "--grid", "motor.omega_rpm=40,80",
         "--method", "time", "--t-max", "8", "--window", "1", "--quiet", "--no-plot"]
#: columns that record when and where a row was computed, not what
NOT_RESULTS = {"wall_seconds", "worker", "finished_at"}


def raw_rows(directory) -> list[dict]:
    with open(Path(directory) / RESULTS, newline="") as fh:
        return list(csv.DictReader(fh))


def test_frameworks_are_der_then_the_beam_regimes_in_order():
    # written out in sweep.task so that plotting need not import the beam solver; they must not drift apart
    from flagbot_sim.beam import REGIMES
    from flagbot_sim.sweep.task import FRAMEWORK_LABELS, FRAMEWORKS
    assert FRAMEWORKS == ("der", *REGIMES)
    assert set(FRAMEWORK_LABELS) == set(FRAMEWORKS)


# ---------------------------------------------------------------- grid
def test_ranges_are_inclusive_and_exact():
    grid = parse_grid(["n=2,3", "motor.omega_rpm=20:250:10", "L=0.09:0.13:0.02", "head.C1=1,2:3:0.5"])
    assert grid["robot.n_flagella"] == [2, 3] and all(type(v) is int for v in grid["robot.n_flagella"])
    rpm = grid["motor.omega_rpm"]
    assert len(rpm) == 24 and rpm[0] == 20 and rpm[-1] == 250 and rpm[5] == 70
    assert grid["flagellum.length"] == [0.09, 0.11, 0.13]        # no 0.10999999999999999 from float steps
    assert grid["head.C1"] == [1, 2.0, 2.5, 3.0]
    with pytest.raises(SweepError, match="motor.omega_rpm.*start:stop:step"):
        parse_grid(["rpm=20:250:10:5"])


@pytest.mark.parametrize("grid, needle", [
    (["robot.n_flagela=2,3"], "robot.n_flagela"),
    (["bogus=1,2"], "bogus"),
    (["n=2,x"], "robot.n_flagella"),
    (["n=0,2"], "robot.n_flagella"),
    (["motor.omega_rpm=250:20:10"], "motor.omega_rpm"),
    (["rpm=20:250:0"], "motor.omega_rpm"),
    (["rpm=20:250"], "motor.omega_rpm"),
    (["flagellum.length=-0.1"], "flagellum.length"),
    (["flagellum.edge_length=0.2"], "flagellum.edge_length"),       # longer than the flagellum: a combination
    (["n=2,2"], "robot.n_flagella"),
    (["n=2", "robot.n_flagella=3"], "robot.n_flagella"),
    (["numerics.linear_solver=arrow,lapack"], "numerics.linear_solver"),
])
def test_bad_grid_is_a_one_line_error_naming_the_key(tmp_path, capsys, grid, needle):
    argv = ["sweep", "design2", "--out", str(tmp_path / "out"), "--quiet"]
    for g in grid:
        argv += ["--grid", g]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and needle in err and "\n" not in err, err
    assert not (tmp_path / "out").exists()          # refused before anything was created or computed


@pytest.mark.parametrize("extra, needle", [
    (["--set", "robot.n_flagella=3", "--grid", "n=2"], "robot.n_flagella"),
    (["--grid", "n=2", "--frameworks", "der,fem"], "--frameworks"),
    (["--grid", "n=2", "--t-max", "2", "--window", "1"], "--t-max"),
])
def test_bad_options_are_one_line_errors(tmp_path, capsys, extra, needle):
    assert main(["sweep", "design2", "--out", str(tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and needle in err and "\n" not in err, err


# ---------------------------------------------------------------- engines
@pytest.fixture(scope="module")
def three_engines(tmp_path_factory):
    base = tmp_path_factory.mktemp("engines")
    out = {}
    for engine in ("serial", "local", "dask"):
        d = base / engine
        assert main(["sweep", *SMALL, "--out", str(d), "--engine", engine, "--workers", "2"]) == 0
        out[engine] = raw_rows(d)
    return out


def test_serial_local_pool_and_dask_give_identical_numbers(three_engines):
    def table(rows):
        return {(r["point"], r["framework"]): {k: v for k, v in r.items() if k not in NOT_RESULTS} for r in rows}
    serial = table(three_engines["serial"])
    assert len(serial) == 4 * 4 and len(three_engines["serial"]) == 16      # 4 points x 4 frameworks, no repeats
    for engine in ("local", "dask"):
        other = table(three_engines[engine])
        assert other.keys() == serial.keys()
        for key in serial:
            assert other[key] == serial[key], (engine, key)     # the CSV text: bit-identical floats
    # the comparison is not vacuous: the points differ from each other and every DER run became steady
    der = [r for r in three_engines["serial"] if r["framework"] == "der"]
    assert len({r["v"] for r in der}) == 4 and all(r["converged"] == "True" for r in der)
    assert all(float(r["sim_time"]) < 8 and r["hit_cap"] == "False" for r in der)


def test_pool_and_dask_really_ran_elsewhere(three_engines):
    here = f":{os.getpid()}"
    assert all(r["worker"].endswith(here) for r in three_engines["serial"])
    for engine in ("local", "dask"):
        assert not any(r["worker"].endswith(here) for r in three_engines[engine]), engine


def test_dask_local_cluster_listens_on_loopback_only():
    psutil = pytest.importorskip("psutil")
    base = load_scene("design2", ["flagellum.length=0.05"])
    settings = SteadySettings(t_max=3.0, window=1.0, rtol=1e-3)
    tasks = [make_task(base, f"p{i}", {"motor.omega_rpm": rpm}, settings, ("lb",)) for i, rpm in enumerate((40, 80))]
    gen = run_tasks(tasks, "dask", workers=2)
    first = next(gen)             # the cluster is up and working
    me = psutil.Process()
    def inet(p):     # psutil < 6 calls it connections()
        return (getattr(p, "net_connections", None) or p.connections)(kind="inet")
    listeners = [c.laddr for p in [me, *me.children(recursive=True)] for c in inet(p)
                 if c.status == psutil.CONN_LISTEN]
    rest = list(gen)
    assert len(listeners) >= 3     # scheduler + two workers at least
    assert all(addr.ip == "127.0.0.1" for addr in listeners), listeners
    assert {first["point"], *(r["point"] for r in rest)} == {"p0", "p1"}


# ---------------------------------------------------------------- steady state
def test_der_stops_at_a_detected_steady_state_that_a_long_run_confirms():
    scene = load_scene("design2", ["flagellum.length=0.05", "motor.omega_rpm=80"])
    row = run_der(scene, SteadySettings(t_max=20.0, window=1.0, rtol=1e-3, method="time"))
    assert row["converged"] and not row["hit_cap"] and row["sim_time"] < 6.0
    assert row["change_omega_h"] < 1e-3 and row["change_v"] < 1e-3
    sim = Simulation(scene)
    sim.run(15.0)
    ref = sim.observer.window_rates(1.0)
    assert row["v"] == pytest.approx(ref["v"], rel=2e-3)
    assert row["omega_h"] == pytest.approx(ref["omega_h"], rel=2e-3)


def test_a_run_that_cannot_settle_reports_the_cap():
    scene = load_scene("design2", ["flagellum.length=0.05", "motor.omega_rpm=80"])
    row = run_der(scene, SteadySettings(t_max=4.0, window=1.0, rtol=1e-14, method="time"))
    assert row["hit_cap"] and not row["converged"] and row["steps"] == 400
    assert math.isfinite(row["v"]) and row["v"] > 0        # still reports its last-window rates


def test_cap_hits_are_in_the_csv_and_the_summary(tmp_path, capsys):
    out = tmp_path / "cap"
    code = main(["sweep", "design2", "--set", "flagellum.length=0.05", "--grid", "rpm=40,80", "--t-max", "3",
                 "--window", "1", "--rtol", "1e-14", "--frameworks", "der,nlb", "--out", str(out), "--quiet",
                 "--method", "time"])
    assert code == 0
    rows = read_results(out)
    der = [r for r in rows if r["framework"] == "der"]
    assert len(der) == 2 and all(r["hit_cap"] and not r["converged"] for r in der)
    assert not any(r["hit_cap"] for r in rows if r["framework"] == "nlb")
    assert "2 DER runs hit the time cap" in capsys.readouterr().out


def test_steady_method_solves_each_point_directly_and_agrees_with_time_stepping(tmp_path):
    """The default method: every DER row is the relative equilibrium (no simulated time), stable, with its
    efficiency; and it agrees with the time-stepped method at the paper's dt (implicit Euler's own error, ~1%)."""
    rows = {}
    for method in ("steady", "time"):
        out = tmp_path / method
        assert main(["sweep", "design2", "--set", "flagellum.length=0.05", "--grid", "rpm=40,80", "--method",
                     method, "--frameworks", "der,lb", "--out", str(out), "--quiet", "--no-plot"]) == 0
        rows[method] = {r["omega_T_rpm"]: r for r in read_results(out) if r["framework"] == "der"}
    for rpm, st in rows["steady"].items():
        ts = rows["time"][rpm]
        assert st["method"] == "steady" and st["converged"] and st["stable"] == "True" and math.isnan(st["sim_time"])
        assert st["residual"] < 1e-6 and st["steps"] < 40           # Newton iterations, not time steps
        assert st["v"] == pytest.approx(ts["v"], rel=3e-2) and st["omega_h"] == pytest.approx(ts["omega_h"], rel=1e-2)
        assert st["power"] == pytest.approx(st["motor_torque"] * st["omega_T"], rel=1e-12) and st["power"] > 0
        assert st["cost_of_transport"] > 0
    lb = [r for r in read_results(tmp_path / "steady") if r["framework"] == "lb"]
    assert all(r["method"] == "beam" and r["motor_torque"] > 0 for r in lb)


# ---------------------------------------------------------------- resume
RESUME_ARGS = ["design2", "--set", "flagellum.length=0.05", "--grid", "n=2,3", "--grid", "rpm=30:80:10",
               "--t-max", "18", "--window", "1", "--rtol", "1e-14", "--quiet", "--no-plot"]
# 12 points, all capped at t_max: ~0.5 s each, so the interrupted run still has seconds of work left when the
# signal arrives (at 0.2 s per point a loaded CI machine once let it finish first)


def _complete_points(rows):
    by = {}
    for r in rows:
        by.setdefault(r["point"], []).append(r)
    return {k: v for k, v in by.items() if len(v) == 4}


@pytest.mark.parametrize("sig, engine", [(signal.SIGKILL, "serial"), (signal.SIGINT, "local"),
                                         (signal.SIGTERM, "local")])
def test_killed_sweep_resumes_computing_only_the_missing_points(tmp_path, capsys, sig, engine):
    psutil = pytest.importorskip("psutil")
    out = tmp_path / "resume"
    argv = ["sweep", *RESUME_ARGS, "--out", str(out), "--engine", engine, "--workers", "2"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    # a runner started in the background of a non-interactive shell inherits SIGINT ignored, and Python keeps
    # it ignored: give the sweep the SIGINT disposition of a foreground command
    proc = subprocess.Popen([sys.executable, "-m", "flagbot_sim", *argv], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    children = set()
    deadline = time.time() + 120
    try:
        while time.time() < deadline:
            try:
                children |= {c.pid for c in psutil.Process(proc.pid).children(recursive=True)}
            except psutil.NoSuchProcess:
                pass
            csv_path = out / RESULTS
            if csv_path.exists() and csv_path.read_text().count("\n") >= 1 + 2 * 4:
                break
            assert proc.poll() is None, "the sweep ended before it could be interrupted: " + proc.stderr.read()
            time.sleep(0.02)
        os.kill(proc.pid, sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    if sig != signal.SIGKILL:
        word = "interrupted" if sig == signal.SIGINT else "terminated"
        assert proc.returncode == 128 + sig and word in err and "rerun the same command" in err, err
        def alive():
            out = []
            for pid in children:
                try:
                    if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                        out.append(pid)
                except psutil.NoSuchProcess:
                    pass
            return out
        until = time.time() + 10
        while alive() and time.time() < until:
            time.sleep(0.1)
        assert children and not alive()          # the pool's workers were stopped with it
    else:
        assert proc.returncode == -signal.SIGKILL
    # a kill can land between the rows of one point or inside a line: simulate both on top of the real kill
    text = (out / RESULTS).read_text()
    lines = text.splitlines(keepends=True)
    (out / RESULTS).write_text("".join(lines[:-1]) + "robot.n_flagella=3;motor.omega_rpm=80.0,3,80.0,3,0.0")
    before = _complete_points(read_results(out))
    assert 0 < len(before) < 12

    t_restart = time.time()
    capsys.readouterr()
    assert main(["sweep", *RESUME_ARGS, "--out", str(out), "--engine", "serial"]) == 0
    assert f"computing {12 - len(before)} " in capsys.readouterr().err
    rows = read_results(out)
    keys = [(r["point"], r["framework"]) for r in rows]
    assert len(keys) == len(set(keys)) == 12 * 4                     # every point once, nothing duplicated
    after = _complete_points(rows)
    assert len(after) == 12
    for point, old_rows in before.items():                            # finished points were not recomputed
        assert sorted(r["finished_at"] for r in after[point]) == sorted(r["finished_at"] for r in old_rows)
    new_points = {r["point"] for r in rows if r["finished_at"] >= t_restart}
    assert new_points == set(after) - set(before)
    assert len((out / RESULTS).read_text().splitlines()) == 1 + 48   # header + rows, no torn line left


def test_a_different_sweep_in_the_same_directory_is_refused(tmp_path, capsys):
    out = str(tmp_path / "one")
    base = ["sweep", "design2", "--set", "flagellum.length=0.05", "--t-max", "3", "--window", "1",
            "--frameworks", "lb", "--out", out, "--quiet", "--no-plot"]
    assert main([*base, "--grid", "rpm=40,80"]) == 0
    capsys.readouterr()
    assert main([*base, "--grid", "rpm=40,80"]) == 0
    assert "computing 0 " in capsys.readouterr().err                       # same sweep: resumes, nothing to do
    assert main([*base, "--grid", "rpm=40,90"]) == 2
    err = capsys.readouterr().err.strip()
    assert "different sweep" in err and "motor.omega_rpm" in err and "\n" not in err
    assert main([*base, "--set", "head.C1=3", "--grid", "rpm=40,80"]) == 2
    assert "head.C1" in capsys.readouterr().err
    assert len(read_results(out)) == 2                                   # the refused runs wrote nothing


def test_dask_engine_submits_to_the_given_scheduler(tmp_path):
    distributed = pytest.importorskip("distributed")
    import logging
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR) as cluster, \
            distributed.Client(cluster) as client:
        worker_pids = set(client.run(os.getpid).values())
        out = tmp_path / "remote"
        assert main(["sweep", "design2", "--set", "flagellum.length=0.05", "--grid", "rpm=40,80", "--t-max", "3",
                     "--window", "1", "--frameworks", "der,lb", "--engine", "dask", "--scheduler",
                     cluster.scheduler_address, "--out", str(out), "--quiet", "--no-plot"]) == 0
    rows = read_results(out)
    assert len(rows) == 4 and {int(r["worker"].rsplit(":", 1)[1]) for r in rows} == worker_pids


def test_a_sweep_names_a_built_in_scene_the_same_on_every_checkout(tmp_path):
    """sweep.json is committed and shared: a built-in scene is written as its place in the package, not as this
    checkout's absolute path; any other file keeps the path it was given."""
    from flagbot_sim.scene_files import portable_source, resolve_scene_path
    assert portable_source(str(resolve_scene_path("design1"))) == "flagbot_sim/scenes/design1.toml"
    own = tmp_path / "mine.toml"
    own.write_text("")
    assert portable_source(str(own)) == str(own)
    assert portable_source(None) is None


def test_each_points_beam_rows_count_the_mass_of_that_points_robot():
    """The cost of transport of the beam rows uses the robot of their own point (its mass built once per point
    and shared by the regimes): points with 2 and 3 flagella, one after the other, each against its own network."""
    from flagbot_sim.physics.network import build_network
    from flagbot_sim.physics.observe import efficiency
    from flagbot_sim.physics.medium import head_torque_coefficient
    from flagbot_sim.scene import load_scene
    from flagbot_sim.sweep.task import SteadySettings, make_task, run_point, task_scene
    base = load_scene("design2", ["flagellum.length=0.05"])
    settings = SteadySettings(t_max=20.0, window=1.0, rtol=1e-4)
    for n in (2, 3, 2):
        task = make_task(base, f"n{n}", {"robot.n_flagella": n}, settings, ("lb", "nlb-nohead", "nlb"))
        scene = task_scene(task)
        mass = float(build_network(scene).node_mass.sum())
        for row in run_point(task)["rows"]:
            torque = head_torque_coefficient(scene) * row["omega_h"]
            expected = efficiency(torque, scene.omega_T, row["v"], mass)["cost_of_transport"]
            assert row["cost_of_transport"] == pytest.approx(expected, rel=1e-12), (n, row["framework"])


def test_a_sweep_from_the_command_line_ends_fast_with_everything_written(tmp_path):
    """`flagbot sweep` ends as the compute-only commands do (cli.FAST_EXIT: the final garbage collection skipped),
    so nothing it wrote may depend on that collection: the whole process leaves every point's rows, the summary
    and the figures behind."""
    import json
    import subprocess
    import sys
    from pathlib import Path
    out = tmp_path / "out"
    flagbot = Path(sys.executable).parent / "flagbot"
    p = subprocess.run([str(flagbot), "sweep", "design2", "--set", "flagellum.length=0.05", "--grid", "rpm=40,80",
                        "--frameworks", "der,lb", "--out", str(out), "--quiet"], capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    rows = read_results(out)
    assert len(rows) == 4 and {(r["framework"], r["omega_T_rpm"]) for r in rows} == \
        {(f, rpm) for f in ("der", "lb") for rpm in (40.0, 80.0)}
    assert json.loads((out / "summary.json").read_text())["groups"]
    assert (out / "speed_vs_omega.png").stat().st_size > 1000


@pytest.mark.parametrize("its_fork_server", [True, False])
def test_only_the_sweeps_own_fork_server_skips_the_interpreters_teardown(its_fork_server):
    """The fork server (a child of the sweep, which names itself in the environment: workers.context) ends
    without the interpreter's teardown, which only kept the sweep's output pipes open ~0.3 s after the sweep ended;
    any other process that imports the preload module keeps its exit handlers."""
    from flagbot_sim.workers import FORK_SERVER_PARENT_ENV
    code = ("import atexit\n"
            "atexit.register(print, 'exit handlers ran', flush=True)\n"
            "import flagbot_sim.sweep.preload\n")
    env = dict(os.environ, **{FORK_SERVER_PARENT_ENV: str(os.getpid() if its_fork_server else 1)})
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert ("exit handlers ran" in p.stdout) is not its_fork_server


@pytest.mark.parametrize("argv, local", [
    (["design2", "--grid", "n=2,3"], True),
    (["design2", "--engine", "local", "--grid", "n=2,3"], True),
    (["design2", "--engine=local"], True),
    (["design2", "--engine", "serial", "--grid", "n=2,3"], False),
    (["design2", "--engine=dask", "--scheduler", "tcp://127.0.0.1:1"], False),
    (["design2", "--grid", "n=2,3", "--help"], False),
    (["-h"], False),
    (["design2", "--", "--engine", "serial"], True),
])
def test_the_command_line_starts_the_fork_server_early_only_for_the_local_engine(argv, local):
    """`flagbot sweep` starts its workers' fork server before its own imports when argparse will choose the local
    engine (the default) and run the sweep; not for --help or another engine."""
    from flagbot_sim.workers import wants_local_engine
    assert wants_local_engine(argv) is local
