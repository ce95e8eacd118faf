"""Start-up time of ``flagbot run``, measured as whole processes the way a user starts them.

    flagbot bench startup                 # cold and warm, min / median / max of 3
    flagbot bench startup --breakdown     # plus where a warm start spends its time

*Cold*: ``flagbot run SCENE --duration 1`` with ``NUMBA_CACHE_DIR`` pointing to a fresh, empty directory (every
kernel compiles, as on the first run after an install). *Warm*: ``flagbot run SCENE --duration 0.1`` after one
untimed run has filled the kernel cache. Both include the interpreter's start and the ROS wheels' re-exec of it
(their ``.pth`` file restarts Python once with LD_LIBRARY_PATH set). The machine is shared: the load average
before and after is printed with the figures, and only figures taken on a quiet machine are worth quoting.
"""
from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: the phases of a warm start, timed inside one child process (perf_counter stamps between the steps)
BREAKDOWN_CODE = r"""
import json, sys, time
t = [time.perf_counter()]
marks = {}
def mark(name):
    now = time.perf_counter(); marks[name] = now - t[0]; t[0] = now
from flagbot_sim.cli import process_age;          mark("flagbot_sim.cli + scene (argparse, tomllib)")
age = process_age() - sum(marks.values())
import numpy;                                      mark("numpy")
import scipy.sparse;                               mark("scipy.sparse")
import scipy.linalg, scipy.sparse.linalg;          mark("scipy.linalg + scipy.sparse.linalg")
import numba;                                      mark("numba")
import flagbot_sim.physics;                        mark("flagbot_sim.physics (its own modules)")
from flagbot_sim.scene import load_scene
scene = load_scene(sys.argv[1]);                   mark("load_scene")
sim = flagbot_sim.physics.Simulation(scene);       mark("Simulation(): model set-up + kernel cache loads")
sim.run(0.1);                                      mark("10 steps (first calls of the step kernels)")
sim.summary();                                     mark("summary")
again = flagbot_sim.physics.Simulation(scene);     mark("a second Simulation() (kernels in memory)")
again.run(0.1);                                    mark("10 more steps (kernels in memory)")
print(json.dumps({"age": age, "marks": marks}))
if sys.argv[2] == "fast":
    from flagbot_sim.cliutil import fast_exit
    fast_exit()                                    # as flagbot run ends
print(time.monotonic(), file=sys.stderr)
"""


def flagbot_command() -> list[str]:
    """``flagbot`` as installed next to this interpreter (the console script users type), else ``-m``."""
    script = Path(sys.executable).with_name("flagbot")
    return [str(script)] if script.exists() else [sys.executable, "-m", "flagbot_sim"]


#: the children run from a neutral directory: with `python -c` / `-m` the working directory comes first on
#: sys.path, and a checkout there would be imported instead of the installed package
NEUTRAL_CWD = tempfile.gettempdir()


def _env(**extra) -> dict:
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    # a fresh interpreter as a user gets it: the ROS wheels' re-exec happens again, as it does from a shell
    for key in ("_ROS_WHEELS_BOOTSTRAP_COMPLETE",):
        env.pop(key, None)
    env.update(extra)
    return env


def time_process(cmd: list[str], env: dict) -> float:
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=NEUTRAL_CWD)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed (exit {p.returncode}): {p.stderr.strip()[-500:]}")
    return wall


def stats(values: list[float]) -> str:
    return f"{min(values):6.2f} / {statistics.median(values):6.2f} / {max(values):6.2f}"


def load() -> str:
    try:
        return "load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    except OSError:
        return "load average unknown"


def run(args) -> int:
    from ..scene import SceneError, load_scene
    if args.repeat < 1:
        raise SceneError(f"--repeat must be at least 1, got {args.repeat}")
    load_scene(args.scene)                          # a bad scene is refused before anything is timed
    scene = str(Path(args.scene).resolve()) if Path(args.scene).is_file() else args.scene   # children: NEUTRAL_CWD
    flagbot = flagbot_command()
    run_cmd = [*flagbot, "run", scene, "--quiet"]
    print(f"start-up of `{' '.join([Path(flagbot[0]).name, *flagbot[1:], 'run', args.scene])}` as whole processes, "
          f"wall seconds, min / median / max of {args.repeat}; {os.cpu_count()} cores, {load()}")
    rows = []
    py = [sys.executable, "-c", "pass"]
    rows.append(("python -c pass", [time_process(py, _env()) for _ in range(args.repeat)]))
    rows.append(("python -c pass, without the ROS wheels' re-exec",
                 [time_process(py, _env(_ROS_WHEELS_BOOTSTRAP_COMPLETE="1")) for _ in range(args.repeat)]))
    time_process([*run_cmd, "--duration", "0.1"], _env())           # fill the kernel cache (untimed)
    warm = [time_process([*run_cmd, "--duration", "0.1"], _env()) for _ in range(args.repeat)]
    rows.append(("warm: --duration 0.1 (kernel cache filled)", warm))
    if not args.no_cold:
        cold = []
        for _ in range(args.repeat):
            cache = tempfile.mkdtemp(prefix="flagbot_cold_cache_")
            try:
                cold.append(time_process([*run_cmd, "--duration", "1"], _env(NUMBA_CACHE_DIR=cache)))
            finally:
                shutil.rmtree(cache, ignore_errors=True)
        rows.append(("cold: --duration 1 (empty kernel cache)", cold))
    width = max(len(r[0]) for r in rows)
    for label, values in rows:
        print(f"  {label:{width}s}  {stats(values)}")
    print(f"  ({load()} after)")
    if args.breakdown:
        print_breakdown(scene)
    return 0


def _breakdown_process(scene: str, exit_mode: str) -> tuple[dict, float]:
    """(the phases, the seconds from the end of the work to the process's end) of one warm start."""
    import json
    p = subprocess.run([sys.executable, "-c", BREAKDOWN_CODE, scene, exit_mode], env=_env(), capture_output=True,
                       text=True, cwd=NEUTRAL_CWD)
    ended = time.monotonic()
    if p.returncode != 0:
        raise RuntimeError(f"breakdown failed: {p.stderr.strip()[-500:]}")
    return json.loads(p.stdout.strip().splitlines()[-1]), ended - float(p.stderr.strip().splitlines()[-1])


def print_breakdown(scene: str) -> None:
    data, fast = _breakdown_process(scene, "fast")
    _, slow = _breakdown_process(scene, "plain")
    rows = [("interpreter start, site, the ROS wheels' re-exec", data["age"]), *data["marks"].items(),
            ("interpreter shutdown (gc.freeze first, as flagbot run does)", fast),
            ("interpreter shutdown without gc.freeze, for comparison", slow)]
    width = max(len(k) for k, _ in rows)
    print(f"warm start of {scene}, one process, seconds (the two 'kernels in memory' lines and the last one are "
          "for comparison, not part of a run):")
    for k, v in rows:
        print(f"  {k:{width}s}  {v:6.3f}")
