"""A read-only install (a system prefix, a container image) still caches its compiled kernels: numba falls back to
a per-user cache directory, so only the first run compiles, and nothing is written into the package."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cli_helpers import ROOT


def _run(cmd, env, readonly_dir):
    if os.geteuid() == 0:
        # root writes through file modes: make the copy read-only with a bind mount in a private mount namespace
        # (nothing outlives the command)
        if shutil.which("unshare") is None:
            pytest.skip("running as root without unshare: cannot make a read-only directory")
        script = (f"mount --bind {readonly_dir} {readonly_dir} && mount -o remount,ro,bind {readonly_dir} && "
                  + " ".join(f"'{c}'" for c in cmd))
        cmd = ["unshare", "--mount", "sh", "-c", script]
    # cwd outside the checkout: ``python -m`` puts the working directory first on sys.path
    return subprocess.run(cmd, env=env, cwd=readonly_dir.parent, capture_output=True, text=True, timeout=600)


def test_kernels_of_a_read_only_install_are_cached_per_user(tmp_path):
    site = tmp_path / "site"
    shutil.copytree(ROOT / "flagbot_sim", site / "flagbot_sim", ignore=shutil.ignore_patterns("__pycache__"))
    if os.geteuid() != 0:
        for p in [site, *site.rglob("*")]:
            p.chmod(p.stat().st_mode & ~0o222 if p.is_file() else 0o555)
    cache_home = tmp_path / "cache"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(PYTHONPATH=str(site), XDG_CACHE_HOME=str(cache_home), HOME=str(tmp_path),
               PYTHONDONTWRITEBYTECODE="1")
    cmd = [sys.executable, "-m", "flagbot_sim", "run", "design1", "--duration", "0.2", "--json"]
    first = _run(cmd, env, site)
    second = _run(cmd, env, site)
    where = _run([sys.executable, "-c", "import flagbot_sim; print(flagbot_sim.__file__)"], env, site)
    assert where.stdout.startswith(str(site)), where.stdout
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    a, b = json.loads(first.stdout), json.loads(second.stdout)
    assert "compiling kernels" in first.stderr and "compiling kernels" not in second.stderr
    assert b["compile_seconds"] < 0.5 * a["compile_seconds"] and a["v"] == b["v"]
    cached = list(cache_home.rglob("*.nbi"))
    assert cached, "numba wrote no index in the per-user cache"
    assert not list(site.rglob("__pycache__")), "something was written into the read-only package"
