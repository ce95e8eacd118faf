"""npm packages for the tests that run real JavaScript clients under Node (tests/node/).

:func:`node_modules` installs tests/node/package.json's packages from the npm registry once, into a cache outside
the repository (``$FLAGBOT_NPM_CACHE``, else ``$XDG_CACHE_HOME/flagbot_sim/npm`` or ``~/.cache/flagbot_sim/npm``),
in a folder named by the hash of package.json: a changed package.json installs anew, and a finished install is
moved into place in one rename, so that test runs in parallel never see half an install.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

NODE_DIR = Path(__file__).resolve().with_name("node")
PACKAGE_JSON = NODE_DIR / "package.json"


def cache_root() -> Path:
    if os.environ.get("FLAGBOT_NPM_CACHE"):
        return Path(os.environ["FLAGBOT_NPM_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or (Path.home() / ".cache")
    return Path(base) / "flagbot_sim" / "npm"


def require_node() -> tuple[str, str]:
    """Paths of node and npm; the test is skipped without them (outside CI), and fails without them in CI."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node and npm:
        return node, npm
    if os.environ.get("CI"):
        pytest.fail("node and npm are needed for the JavaScript client tests and are not on PATH")
    pytest.skip("node and npm are not on PATH")


def node_modules(timeout: float = 600.0) -> Path:
    """The node_modules folder holding tests/node/package.json's packages (installed on first use)."""
    _, npm = require_node()
    digest = hashlib.sha256(PACKAGE_JSON.read_bytes()).hexdigest()[:16]
    root = cache_root()
    final = root / digest
    if (final / "node_modules" / ".flagbot_complete").exists():
        return final / "node_modules"
    root.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f"{digest}.partial.", dir=root))
    try:
        shutil.copy(PACKAGE_JSON, work / "package.json")
        p = subprocess.run([npm, "install", "--no-audit", "--no-fund", "--no-package-lock", "--omit=dev",
                            "--loglevel=error"], cwd=work, capture_output=True, text=True, timeout=timeout)
        if p.returncode != 0:
            raise RuntimeError(f"npm install of {PACKAGE_JSON} failed ({p.returncode}):\n{p.stderr[-3000:]}")
        (work / "node_modules" / ".flagbot_complete").write_text(PACKAGE_JSON.read_text())
        try:
            os.rename(work, final)
        except OSError:            # another run finished first (or a stale incomplete folder is in the way)
            if not (final / "node_modules" / ".flagbot_complete").exists():
                shutil.rmtree(final, ignore_errors=True)
                os.rename(work, final)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return final / "node_modules"


def run_node(script: str, *args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """``node tests/node/SCRIPT ARGS`` with the installed packages; the CompletedProcess (text)."""
    node, _ = require_node()
    env = dict(os.environ, NODE_PATH=str(node_modules()))
    return subprocess.run([node, str(NODE_DIR / script), *args], capture_output=True, text=True, env=env,
                          timeout=timeout)
