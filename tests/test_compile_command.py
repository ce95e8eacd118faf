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
