"""The kernels' compile as a visible step of its own: ``flagbot compile``, the first step of ``flagbot demo`` on an
empty cache, and ``python3 dev.py setup`` (through ``flagbot compile``).

numba compiles the kernels on their first use and keeps the machine code in its on-disk cache, so the compile is
paid once per machine (per cache directory: ``NUMBA_CACHE_DIR`` moves it). Paid inside something else, it looks
like a hang (a node that takes a minute to appear, a timed test that fails); paid here, it shows what it is doing
and for how long. The work itself is :func:`flagbot_sim.physics.warmup.ensure_compiled`; this module only shows it.
"""
from __future__ import annotations

import sys
import threading

from .progress import StatusLine


def compile_kernels(stream=None, prefix: str = "") -> tuple[float, bool]:
    """Compile (empty cache) or load (warm cache) every kernel in this process, showing a status line with the
    elapsed time on ``stream`` (default stderr) while it runs.

    Returns (seconds taken, whether it compiled: the cache was empty). The status shows what ensure_compiled
    says it is doing (its first-run notice) once it says it, before that what the cache's state implies."""
    from .physics import warmup
    warm = warmup.cache_is_warm()
    status = StatusLine(stream or sys.stderr)
    said = []
    lock = threading.Lock()

    def show(text: str | None = None) -> None:
        with lock:
            status.update(status.text if text is None else text)

    def notify(message: str) -> None:
        said.append(message)
        show(prefix + message.removeprefix("flagbot_sim: "))

    show(prefix + ("loading the compiled kernels from the cache" if warm else "compiling kernels (first run only)"))
    done = threading.Event()

    def tick() -> None:             # the elapsed time keeps moving while the compile holds the main thread
        while not done.wait(0.5):
            show()

    ticker = threading.Thread(target=tick, name="compile-status", daemon=True)
    ticker.start()
    try:
        seconds = warmup.ensure_compiled(notify)
    finally:
        done.set()
        ticker.join()
    status.close(None)
    return seconds, bool(said) or not warm


def describe(seconds: float, compiled: bool) -> str:
    """One line saying what :func:`compile_kernels` did."""
    if compiled:
        return f"kernels compiled in {seconds:.1f} s (first run only: later runs load them from the cache)"
    return f"kernels loaded from the cache in {seconds:.1f} s (nothing to compile)"


def compile_bytecode(root: str | None = None) -> int | None:
    """Byte-compile the package's Python modules into their ``__pycache__``, as pip does when it installs a wheel;
    returns how many were (re)written, or None if the package's directory is read-only.

    An editable checkout run with PYTHONDONTWRITEBYTECODE set (as this project's shared machines are) never writes
    them, and then every start compiles every module's source again: 0.14 s of imports against 0.05 s from the
    bytecode, measured in a warm ``flagbot run design1`` (``-X importtime``, the package's own modules). Only
    modules whose source is newer than their bytecode are written. ``root``: the package's directory (default: this
    package's)."""
    import compileall
    import io
    import os
    from contextlib import redirect_stdout
    root = root or os.path.dirname(os.path.abspath(__file__))
    if not os.access(root, os.W_OK):
        return None
    before = {p: os.stat(p).st_mtime_ns for p in _bytecode_files(root)}
    with redirect_stdout(io.StringIO()):
        compileall.compile_dir(root, quiet=2)
    after = {p: os.stat(p).st_mtime_ns for p in _bytecode_files(root)}
    return sum(1 for p, t in after.items() if before.get(p) != t)


def _bytecode_files(root: str) -> list[str]:
    import glob
    import os
    return glob.glob(os.path.join(root, "**", "__pycache__", "*.pyc"), recursive=True)
