"""Helpers shared by every command module: scene arguments, strict JSON output, the version.

A leaf module: it imports nothing from flagbot_sim but :mod:`flagbot_sim.scene` (and the package's
``__version__``), so any command module (beam, sweep, bag tools, ...) can use it without importing
:mod:`flagbot_sim.cli` back.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time
from typing import Any

from . import __version__


def add_scene_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="built-in scene name (design1, design2, clamped_flagellum) or a .toml path")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value, e.g. --set robot.n_flagella=3 --set motor.omega_rpm=150")


def finite_float(text: str, where: str, error: type[Exception] = ValueError) -> float:
    """``text`` as a finite float, else ``error("WHERE: 'TEXT' is not a number" / "... is not finite")``."""
    try:
        x = float(text)
    except ValueError:
        raise error(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(x):
        raise error(f"{where}: {text!r} is not finite")
    return x


def json_default(o):
    """numpy arrays and scalars as plain JSON values (for ``json.dumps(default=...)``)."""
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def finite_or_none(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, +-Inf) replaced by None, recursively (strict JSON has neither)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    if hasattr(obj, "tolist"):               # numpy array or scalar
        return finite_or_none(obj.tolist())
    return obj


def finite_text(value, spec: str, missing: str = "--") -> str:
    """``value`` formatted with ``spec``, or ``missing`` when it is None or not finite (never 'nan')."""
    if value is None or not isinstance(value, (int, float)) or not math.isfinite(value):
        return missing
    return format(value, spec)


def dumps(obj: Any, **kwargs) -> str:
    """Strict JSON (RFC 8259): numpy values converted, NaN/Inf written as null, never as bare NaN/Infinity."""
    return json.dumps(finite_or_none(obj), default=json_default, allow_nan=False, **kwargs)


def version_text(prog: str) -> str:
    """What ``PROG --version`` prints: ``flagbot (flagbot_sim) 0.1.0`` (every console script says the same)."""
    return f"{prog} (flagbot_sim) {__version__}"


def add_version_argument(p: argparse.ArgumentParser, prog: str) -> None:
    """``--version`` on a parser: print :func:`version_text` and exit 0 (argparse acts on it before it checks the
    required arguments, so ``cmd_profile --version`` needs no profile)."""
    p.add_argument("--version", action="version", version=version_text(prog),
                   help="print the version of flagbot_sim and exit")


def with_version(obj: Any) -> Any:
    """A JSON result with ``"version"`` (flagbot_sim's) as its first key; a list of results gets it in each
    object, so that a list stays a list for the programs that read it."""
    if isinstance(obj, dict):
        return {"version": __version__, **{k: v for k, v in obj.items() if k != "version"}}
    if isinstance(obj, (list, tuple)):
        return [with_version(x) if isinstance(x, dict) else x for x in obj]
    return obj


def json_output(obj: Any, **kwargs) -> str:
    """The JSON a command prints or writes for its user (``--json``, ``summary.json``, ...): strict JSON
    (:func:`dumps`) with the version of flagbot_sim that made it (:func:`with_version`)."""
    return dumps(with_version(obj), **kwargs)


#: when this module was imported: the fallback origin of ``startup_seconds`` where /proc is not available
_IMPORTED = time.perf_counter()


def _proc_stat(pid: int | str = "self") -> list[bytes]:
    """The fields of /proc/PID/stat after the command name, so that ``fields[k - 3]`` is proc(5)'s field k
    (Linux only: OSError elsewhere)."""
    with open(f"/proc/{pid}/stat", "rb") as f:
        # the command name (field 2) may hold spaces and parentheses: split after the last ')'
        return f.read().rsplit(b")", 1)[1].split()


def process_age() -> float:
    """Seconds since this process started (Linux: from /proc, so interpreter start-up and the ROS wheels'
    re-exec of the interpreter are included; elsewhere: since this module was imported)."""
    try:
        start_ticks = int(_proc_stat()[19])                 # field 22, starttime, in clock ticks since boot
        with open("/proc/uptime", "rb") as f:
            uptime = float(f.read().split()[0])
        return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return time.perf_counter() - _IMPORTED


def cpu_seconds(pid: int) -> float | None:
    """CPU time (user + system, its waited-for children included) process ``pid`` has used so far, from /proc;
    None where that cannot be read (not Linux, or the process is gone). A process that is working (compiling,
    stepping) sees it grow even on a loaded machine; one that sleeps or waits does not."""
    try:
        fields = _proc_stat(pid)
        return sum(int(x) for x in fields[11:15]) / os.sysconf("SC_CLK_TCK")   # fields 14-17: utime .. cstime
    except (OSError, ValueError, IndexError):
        return None


def make_out_dir(path, option: str = "--out") -> "Path":
    """Create the output directory ``path`` of ``option`` (and its parents) before any work is done; a path that
    is a file or cannot be created is refused with a one-line reason (a SceneError), not a traceback after the
    work. Output files are checked by :func:`check_out_file`."""
    from pathlib import Path

    from .scene import SceneError
    out = Path(path)
    if str(path).strip() == "":
        raise SceneError(f"{option}: the directory name is empty")
    if out.exists() and not out.is_dir():
        raise SceneError(f"{option} {out}: exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SceneError(f"{option} {out}: cannot create the directory: {exc.strerror or exc}") from None
    return out


def check_out_file(path, option: str) -> "Path":
    """Check, before any work is done, that the output file ``path`` given with ``option`` (``--plot``,
    ``--gif``, ...) can be written: it is not a directory (or a FIFO, a device), its directory exists, and a file
    can be created there (or the existing one written). A refusal is a SceneError naming the option and the
    path, one line: the command exits 2 at once instead of a traceback after the work. Leaves nothing behind (a
    file created to find out is removed)."""
    from pathlib import Path

    from .scene import SceneError
    p = Path(path)
    if str(path).strip() == "":
        raise SceneError(f"{option}: the file name is empty")
    if p.is_dir():
        raise SceneError(f"{option} {p}: is a directory; give a file name, e.g. {p / 'name'}{p.suffix}")
    if p.exists() and not p.is_file():
        raise SceneError(f"{option} {p}: exists and is not a regular file")
    parent = p.parent
    if not parent.exists():
        raise SceneError(f"{option} {p}: directory {parent} does not exist")
    if not parent.is_dir():
        raise SceneError(f"{option} {p}: {parent} is not a directory")
    existed = p.exists()
    try:
        fd = os.open(p, os.O_WRONLY | os.O_APPEND if existed else os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except OSError as exc:
        raise SceneError(f"{option} {p}: cannot write it: {exc.strerror or exc}") from None
    os.close(fd)
    if not existed:
        os.unlink(p)
    return p


def check_figure_file(path, option: str) -> "Path":
    """:func:`check_out_file` for a figure that matplotlib writes in the format its suffix names (``.png``,
    ``.svg``, ``.pdf``, ...): a path without a suffix or with one matplotlib cannot write is refused too."""
    from matplotlib.backend_bases import FigureCanvasBase

    from .scene import SceneError
    p = check_out_file(path, option)
    kinds = FigureCanvasBase.get_supported_filetypes()
    suffix = p.suffix.lower().removeprefix(".")
    if suffix not in kinds:
        what = "has no suffix" if not suffix else f"matplotlib cannot write .{suffix} figures"
        raise SceneError(f"{option} {p}: {what}; the suffix names the format: "
                         f"{', '.join('.' + k for k in sorted(kinds))}")
    return p


def broken_pipe_exit() -> int:
    """What a command does when its reader went away (``flagbot scenes | head -3``): no traceback; stdout is
    pointed at /dev/null so that the interpreter's final flush does not raise again (Python's signal docs)."""
    import sys
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    return 1


def fast_exit() -> None:
    """Make the interpreter's shutdown cheap: move every object into the permanent generation (``gc.freeze``), so
    the collections at finalization do not walk the ~10^6 objects numba, scipy and the model leave behind. That
    walk took 0.4-0.5 s, a third of a warm ``flagbot run``, and most of sim_node's exit after SIGINT (0.35-0.5 s
    of CPU, 0.5-0.9 s of wall time on a shared host); objects still die by reference counting (the ROS context
    and its DDS participant too: the node leaves the graph as before). Call it only once everything written has
    been closed: it flushes stdout and stderr."""
    import gc
    import sys
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except BrokenPipeError:        # its reader went away: nothing left to say to it
            if stream is sys.stdout:
                broken_pipe_exit()
        except (OSError, ValueError):  # closed
            pass
    gc.freeze()
