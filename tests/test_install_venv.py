"""A pip user's install, end to end: the wheel into a fresh venv that holds only the ROS 2 wheels.

The venv is made from the base interpreter (nothing of the repository's .venv), gets the three ROS 2 wheels, then
``pip install flagbot_sim-*.whl`` with no dependency option: install_requires alone must bring everything. Then, from
that venv, as a user runs them: ``flagbot run`` (compiled kernels), a 2-point sweep with its figures, a recording
made by ``lib/flagbot_sim/sim_node`` (found as ``ros2 run`` finds it, with a fake python3 first on PATH) and read
back by ``flagbot bag-summary``, and a missing extra's one-line message.

Slow (~1 min: mostly pip unpacking and numba's first compile; docs/install.md has the figures). CI runs it; set
FLAGBOT_SKIP_INSTALL_TEST=1 to skip it locally. pip's cache makes repeated runs download nothing.
"""
import csv
import json
import math
import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from install_helpers import PACKAGE, copy_sources, env_outside, fake_python3, ros2_run_path

pytestmark = pytest.mark.skipif(os.environ.get("FLAGBOT_SKIP_INSTALL_TEST") == "1",
                                reason="FLAGBOT_SKIP_INSTALL_TEST=1")

ROS_WHEELS = ["ros-jazzy-rclpy", "ros-jazzy-common-interfaces", "ros-jazzy-rmw-fastrtps-cpp"]
TIMINGS: dict[str, float] = {}


def _timed(what: str, cmd, **kw) -> subprocess.CompletedProcess:
    t0 = time.perf_counter()
    p = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    TIMINGS[what] = time.perf_counter() - t0
    assert p.returncode == 0, f"{what}: exit {p.returncode}\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    return p


@pytest.fixture(scope="module")
def venv(tmp_path_factory):
    work = tmp_path_factory.mktemp("pip_user")
    # the build runs on a copy, with the test's setuptools (no isolated build env to download); the venv never
    # sees this environment
    src = copy_sources(work / "src")
    _timed("build wheel", [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
                           "-w", work / "dist", src], cwd=work)
    wheel, = (work / "dist").glob(f"{PACKAGE}-*.whl")
    venv = work / "venv"
    env = env_outside(PIP_DISABLE_PIP_VERSION_CHECK="1", PIP_NO_INPUT="1")
    _timed("create venv", [sys.executable, "-m", "venv", "--without-pip", venv], cwd=work, env=env)
    py = venv / "bin" / "python"
    # this environment's pip installs into the venv (--python): the same resolution as the venv's own pip,
    # without bootstrapping one (ensurepip, ~5 s); --no-compile skips byte-compiling every installed module
    # (~7 s; Python compiles what it imports). Neither changes what gets installed.
    pip = [sys.executable, "-m", "pip", "--python", py, "install", "--quiet", "--no-compile"]
    _timed("pip install ROS 2 wheels", [*pip, *ROS_WHEELS], cwd=work, env=env)
    _timed("pip install wheel", [*pip, wheel], cwd=work, env=env)
    # what a user's shell has: the venv's bin/ on PATH, here behind a python3 that is not the venv's
    env["PATH"] = os.pathsep.join([str(fake_python3(work / "fake")), str(venv / "bin"), "/usr/bin", "/bin"])
    print("\n" + "\n".join(f"  {k}: {v:.1f} s" for k, v in TIMINGS.items()))
    return {"dir": work, "py": py, "bin": venv / "bin", "prefix": venv, "env": env}


def test_pip_installed_every_dependency_and_nothing_comes_from_elsewhere(venv):
    p = _timed("pip check", [sys.executable, "-m", "pip", "--python", venv["py"], "check"], cwd=venv["dir"],
               env=venv["env"])
    assert "No broken requirements" in p.stdout
    code = ("import flagbot_sim, numba, mcap, mcap_ros2, matplotlib, scipy, rclpy, sys; "
            "print(flagbot_sim.__file__); print(sys.prefix)")
    p = _timed("imports", [venv["py"], "-c", code], cwd=venv["dir"], env=venv["env"])
    module, prefix = p.stdout.split()
    assert Path(prefix) == venv["prefix"] and Path(module).is_relative_to(venv["prefix"])


def test_flagbot_run_uses_the_compiled_kernels(venv):
    p = _timed("flagbot run (first, compiles)", [venv["bin"] / "flagbot", "run", "design1", "--duration", "2",
                                                 "--json"], cwd=venv["dir"], env=venv["env"], timeout=600)
    out = json.loads(p.stdout)
    assert out["kernels"] == "compiled"
    assert out["steps"] == 200 and out["time"] == pytest.approx(2.0)
    for k in ("omega_h", "omega_t", "v", "wall_seconds"):
        assert math.isfinite(out[k]), k
    # the motor turns head and flagella apart: omega_h + omega_t = omega_T; the robot swims head first
    assert out["omega_h"] > 0 and out["omega_t"] > 0 and out["v"] > 0
    assert out["omega_h"] + out["omega_t"] == pytest.approx(out["omega_T"], rel=0.02)


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR", f"{path.name} is not a PNG"
    return struct.unpack(">II", data[16:24])


def test_a_two_point_sweep_draws_its_figures(venv):
    out = venv["dir"] / "sweep"
    _timed("flagbot sweep", [venv["bin"] / "flagbot", "sweep", "design2", "--set", "flagellum.length=0.05",
                             "--grid", "motor.omega_rpm=40,80", "--t-max", "8", "--window", "1", "--engine",
                             "serial", "--quiet", "--out", out], cwd=venv["dir"], env=venv["env"], timeout=600)
    with open(out / "results.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    der = [r for r in rows if r["framework"] == "der"]
    assert len(der) == 2 and all(math.isfinite(float(r["v"])) and float(r["v"]) > 0 for r in der)
    pngs = sorted(out.glob("*.png"))
    assert {p.name for p in pngs} >= {"speed_vs_omega.png", "head_spin.png", "deflection.png"}
    for png in pngs:
        w, h = _png_size(png)
        assert w >= 400 and h >= 300 and png.stat().st_size > 10_000, f"{png.name}: {w}x{h}, {png.stat().st_size} B"


def test_a_recording_made_through_ros2_run_reads_back(venv, ros):
    from rclpy.qos import qos_profile_sensor_data
    from ros_helpers import spin_until
    from rosgraph_msgs.msg import Clock

    env = dict(venv["env"], AMENT_PREFIX_PATH=str(venv["prefix"]))
    sim_node = ros2_run_path(PACKAGE, "sim_node", env)
    bag = venv["dir"] / "run.mcap"
    omega, t_sim = 10.0, 10.0
    clock = {"t": 0.0}
    sub = ros.create_subscription(Clock, "/clock", lambda m: clock.update(t=m.clock.sec + 1e-9 * m.clock.nanosec),
                                  qos_profile_sensor_data)
    t0 = time.perf_counter()
    proc = subprocess.Popen([str(sim_node), "--ros-args", "-p", f"record:={bag}", "-p", "real_time_factor:=0.0",
                             "-p", f"initial_omega:={omega}", "-p", "marker_rate:=0.0"],
                            cwd=venv["dir"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # stop once the node (as fast as it can go) has published t_sim seconds of simulated time, however long
        # its first step takes (numba compiles the kernels there when this test runs first)
        spin_until(ros, lambda: clock["t"] >= t_sim or proc.poll() is not None, timeout=300,
                   what=f"{t_sim} s of simulated time on /clock")
        assert proc.poll() is None, proc.communicate()[0]
        proc.send_signal(signal.SIGINT)
        output, _ = proc.communicate(timeout=60)
    finally:
        ros.destroy_subscription(sub)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    TIMINGS["sim_node recording"] = time.perf_counter() - t0
    assert proc.returncode == 0, output
    p = _timed("flagbot bag-summary", [venv["bin"] / "flagbot", "bag-summary", bag, "--json"],
               cwd=venv["dir"], env=venv["env"])
    summary = json.loads(p.stdout)
    assert summary["closed"] and summary["ok"], summary
    counts = {t["topic"]: t["count"] for t in summary["topics"]}
    # state topics at publish_rate (50 Hz) of wall time, while the node runs ~50x faster than real time
    assert counts["/joint_states"] >= 3 and counts["/clock"] >= 3
    assert summary["metadata"]["scene"] and summary["metadata"]["package_version"]
    last = summary["steps"][-1]
    assert last["omega_T"] == pytest.approx(omega)
    assert last["omega_h"] + last["omega_t"] == pytest.approx(omega, rel=0.02)


def test_a_missing_extra_is_one_line_naming_it(venv):
    p = subprocess.run([str(venv["bin"] / "flagbot"), "sweep", "design2", "--grid", "rpm=40", "--engine", "dask",
                        "--quiet", "--out", str(venv["dir"] / "dask_sweep")],
                       capture_output=True, text=True, cwd=venv["dir"], env=venv["env"], timeout=300)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines()[-1].endswith("pip install 'flagbot_sim[dask]'"), p.stderr
    print("\n" + "\n".join(f"  {k}: {v:.1f} s" for k, v in TIMINGS.items()))
