"""The package installs as ROS expects: indexed through ament, executables in lib/flagbot_sim/ (ros2 run), and
console scripts on PATH for pip users."""
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from cli_helpers import ROOT
EXECUTABLES = ["flagbot", "sim_node", "beam_node", "cmd_profile", "record", "replay"]


@pytest.fixture(scope="module")
def prefix(tmp_path_factory):
    prefix = tmp_path_factory.mktemp("install")
    # --ignore-installed: without it pip first uninstalls the copy in the running environment (the developer's
    # editable install), as the prefix is not a separate environment to it
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                    "--ignore-installed", "--prefix", str(prefix), str(ROOT)], check=True,
                   cwd=tmp_path_factory.getbasetemp())
    return prefix


def test_package_is_indexed_through_ament(prefix, monkeypatch):
    from ament_index_python.packages import get_package_prefix, get_package_share_directory
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    assert Path(get_package_prefix("flagbot_sim")) == prefix
    share = Path(get_package_share_directory("flagbot_sim"))
    assert (share / "package.xml").is_file()
    assert {p.name for p in (share / "scenes").iterdir()} >= {"design1.toml", "design2.toml",
                                                             "clamped_flagellum.toml"}


@pytest.mark.parametrize("exe", EXECUTABLES)
def test_ros2_run_executables_exist_and_run(prefix, exe):
    path = prefix / "lib" / "flagbot_sim" / exe          # where `ros2 run flagbot_sim EXE` looks
    assert path.is_file() and os.access(path, os.X_OK)
    site = sysconfig.get_path("purelib", vars={"base": str(prefix), "platbase": str(prefix)})
    env = dict(os.environ, PYTHONPATH=site, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    # run from elsewhere so the repository checkout cannot be what gets imported
    p = subprocess.run([str(path), "--help"], capture_output=True, text=True, env=env, cwd=prefix, timeout=120)
    assert p.returncode == 0, p.stderr
    assert "usage" in p.stdout.lower()
    # and pip's console script of the same name sits on PATH (bin/)
    assert (prefix / "bin" / exe).is_file()
