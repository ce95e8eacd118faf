#!/usr/bin/env python3
"""Set up the virtual environment and run the project's jobs with nothing but Python (3.11-3.13) and pip.

    python3 dev.py run      # create .venv if needed, install, compile, run the main job (flagbot demo: ROS nodes)
    python3 dev.py test     # create .venv if needed, install, compile, run the test suite (extra args go to pytest)
    python3 dev.py setup    # only create/update .venv and compile the kernels
    python3 dev.py fuzz [N] # the property tests with fresh random examples, N (default 3000) per test

The Makefile targets call this file. DDS traffic is kept on this machine: every job runs with
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.

Setup ends with `flagbot compile`: the simulator's kernels are compiled into numba's on-disk cache as a step of
their own, with its time printed (tens of seconds on a first run, on a loaded 2-core machine a minute or more),
so that the demo's nodes and the tests start warm and no timed test pays the compile. Later it only loads them
(about a second) and recompiles what an edit made stale.
"""
from __future__ import annotations

import hashlib
import os
import platform
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
PY = VENV / "bin" / "python"
STAMP = VENV / ".flagbot_installed"
INPUTS = ["requirements.txt", "requirements-test.txt", "setup.py", "package.xml"]


def job_env() -> dict:
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("ROS_LOG_DIR", str(ROOT / ".ros_log"))
    env.setdefault("MPLBACKEND", "Agg")
    env["PATH"] = f"{VENV / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return env


def sh(*cmd: str | os.PathLike) -> None:
    print("+", " ".join(map(str, cmd)), flush=True)
    subprocess.run([str(c) for c in cmd], check=True, cwd=ROOT, env=job_env())


def setup() -> None:
    if not ((3, 11) <= sys.version_info[:2] <= (3, 13)):
        # 3.11: the scene files are read with tomllib; 3.13: the newest the ROS 2 Jazzy wheels exist for
        sys.exit(f"dev.py: flagbot_sim needs CPython 3.11-3.13 (ROS 2 Jazzy wheels: 3.10-3.13, tomllib: 3.11+); "
                 f"this is {platform.python_version()}")
    if platform.machine() not in ("x86_64", "AMD64"):
        sys.exit(f"dev.py: ROS 2 Jazzy wheels exist for x86_64 only; this machine is {platform.machine()}")
    if not PY.exists():
        print(f"+ creating {VENV}", flush=True)
        venv.create(VENV, with_pip=True)
    digest = hashlib.sha256(b"".join((ROOT / f).read_bytes() for f in INPUTS)).hexdigest()
    if not (STAMP.exists() and STAMP.read_text() == digest and (VENV / "bin" / "flagbot").exists()):
        sh(PY, "-m", "pip", "install", "--quiet", "--upgrade", "pip")
        sh(PY, "-m", "pip", "install", "--quiet", "-r", "requirements-test.txt")
        sh(PY, "-m", "pip", "install", "--quiet", "--no-deps", "-e", ".")
        STAMP.write_text(digest)
    sh(VENV / "bin" / "flagbot", "compile")


def run(args: list[str]) -> None:
    setup()
    sh(VENV / "bin" / "flagbot", "demo", *args)


def test(args: list[str]) -> None:
    setup()
    sh(PY, "-m", "pytest", "-q", "tests", *args)


def fuzz(args: list[str]) -> None:
    """The suite's property tests draw a fixed set of examples (its verdict is the same on every run); this
    explores: fresh random ones, as many per test as asked."""
    n = args[0] if args and args[0].isdigit() else "3000"
    setup()
    os.environ["FLAGBOT_FUZZ"] = n
    sh(PY, "-m", "pytest", "-q", "tests/test_scene_fuzz.py", "-k", "random or override",
       "--hypothesis-show-statistics", *args[1 if args and args[0].isdigit() else 0:])


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] not in ("setup", "run", "test", "fuzz"):
        sys.exit(__doc__)
    cmd, rest = sys.argv[1], sys.argv[2:]
    try:
        {"setup": lambda a: setup(), "run": run, "test": test, "fuzz": fuzz}[cmd](rest)
    except subprocess.CalledProcessError as exc:
        sys.exit(exc.returncode)


if __name__ == "__main__":
    main()
