"""`flagbot compile`: the kernels' compile as a step of its own (dev.py's setup runs it), so that what follows
starts warm: it fills an empty cache and says how long it took, then only loads, and a run after it compiles
nothing."""
import json
import os
import re
import subprocess
import sys

from cli_helpers import ROOT


def test_compile_fills_an_empty_cache_then_a_run_starts_warm(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PYTHONPATH=str(ROOT))

    def flagbot(*argv):
        p = subprocess.run([sys.executable, "-m", "flagbot_sim", *argv], capture_output=True, text=True, env=env,
                           cwd=ROOT, timeout=900)
        assert p.returncode == 0, p.stdout + p.stderr
        return p

    cold = flagbot("compile")
    assert "NUMBA_CACHE_DIR=" + str(tmp_path / "cache") in cold.stdout
    assert "compiling kernels (first run only" in cold.stderr
    m = re.search(r"^kernels compiled in ([0-9.]+) s \(first run only", cold.stdout, re.M)
    assert m, cold.stdout
    compiled = float(m.group(1))
    assert any((tmp_path / "cache").rglob("*.nbi")) and any((tmp_path / "cache").rglob("*.nbc"))
    warm = flagbot("compile")
    assert "compiling" not in warm.stderr
    assert re.search(r"^kernels loaded from the cache in [0-9.]+ s \(nothing to compile\)$", warm.stdout, re.M)
    # what the cache now holds is what a run uses: no notice, and the run loads faster than the compile took
    run = flagbot("run", "design1", "--duration", "0.2", "--json")
    assert "compiling" not in run.stderr
    assert json.loads(run.stdout)["compile_seconds"] < compiled


def test_compile_writes_the_python_bytecode_a_pip_install_would_and_only_what_is_stale(tmp_path):
    import importlib.util
    import time
    from flagbot_sim.kernels import compile_bytecode
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    for f in (pkg / "__init__.py", pkg / "a.py", pkg / "sub" / "__init__.py", pkg / "sub" / "b.py"):
        f.write_text("X = 1\n")
    assert compile_bytecode(str(pkg)) == 4                  # written even where PYTHONDONTWRITEBYTECODE is set
    assert os.path.exists(importlib.util.cache_from_source(str(pkg / "sub" / "b.py")))
    assert compile_bytecode(str(pkg)) == 0                  # nothing stale: nothing written
    time.sleep(0.01)
    (pkg / "a.py").write_text("X = 2\n")
    os.utime(pkg / "a.py", (time.time() + 5, time.time() + 5))   # (newer than its bytecode on any clock)
    assert compile_bytecode(str(pkg)) == 1
    pkg.chmod(0o555)
    try:
        assert os.access(pkg, os.W_OK) or compile_bytecode(str(pkg)) is None   # (root ignores the mode bits)
    finally:
        pkg.chmod(0o755)
