"""Helpers for the install tests: a clean copy of the sources, `ros2 run`'s lookup, a python3 that is not one."""
from __future__ import annotations

import ast
import os
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "flagbot_sim"
# what a checkout holds besides the sources (at its top level, and anywhere): never part of a build
NOT_SOURCES_TOP = {".venv", ".git", "build", "install", "log", "dist", "out", "sweeps", ".ros_log"}
NOT_SOURCES = shutil.ignore_patterns("__pycache__", "*.egg-info", ".pytest_cache")


def setup_literal(name: str):
    """A literal assigned at the top of setup.py (EXECUTABLES, INSTALL_REQUIRES, EXTRAS_REQUIRE), without running it."""
    for node in ast.parse((ROOT / "setup.py").read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name for t in node.targets):
            return ast.literal_eval(node.value)
    raise LookupError(f"setup.py assigns no {name}")


EXECUTABLES = list(setup_literal("EXECUTABLES"))


def copy_sources(dst: Path) -> Path:
    """The checkout without its venv, git data and build leftovers: builds run there, so a stale build/ in the
    checkout cannot leak into what is installed, and the checkout is never written to."""
    def ignore(directory, names):
        top = NOT_SOURCES_TOP & set(names) if Path(directory) == ROOT else set()
        return top | NOT_SOURCES(directory, names)
    shutil.copytree(ROOT, dst, ignore=ignore, symlinks=True)
    return dst


def fake_python3(directory: Path) -> Path:
    """A directory whose ``python3`` exits 99: put first on PATH, it catches anything that runs "python3"."""
    directory.mkdir(parents=True, exist_ok=True)
    exe = directory / "python3"
    exe.write_text("#!/bin/sh\necho 'the python3 first on PATH was run' >&2\nexit 99\n")
    exe.chmod(0o755)
    return directory


def ros2_run_path(package: str, executable: str, env: dict) -> Path:
    """What `ros2 run PACKAGE EXECUTABLE` executes (ros2cli has no wheels here): the first prefix on
    AMENT_PREFIX_PATH whose ament index lists the package, then <prefix>/lib/<package>/<executable>."""
    for prefix in filter(None, env.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        if (Path(prefix) / "share" / "ament_index" / "resource_index" / "packages" / package).is_file():
            path = Path(prefix) / "lib" / package / executable
            assert path.is_file() and os.access(path, os.X_OK), f"{path}: not an executable"
            return path
    raise AssertionError(f"package {package!r} not found on AMENT_PREFIX_PATH={env.get('AMENT_PREFIX_PATH')!r}")


def env_outside(base: dict | None = None, **changes) -> dict:
    """The environment without what ties a process to the running venv: its PYTHONPATH and the ROS wheels'
    bootstrap (LD_LIBRARY_PATH + the done flag; another venv must set its own libraries)."""
    env = dict(os.environ if base is None else base)
    for var in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE",
                "AMENT_PREFIX_PATH"):
        env.pop(var, None)
    env.update(changes)
    return env

