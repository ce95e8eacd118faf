"""Every command that writes a file checks the path before any work: a missing directory, a directory where a file
should be, a format the suffix does not name are one `error:` line naming the option and the path, exit 2, and
nothing was simulated, read or written (render, bag-summary and bag-recover ended with a FileNotFoundError
traceback after all their work, exit 1)."""
import os
import subprocess
import sys

import pytest

from flagbot_sim.cliutil import check_figure_file, check_out_file, make_out_dir
from flagbot_sim.scene import SceneError

from cli_helpers import ROOT, flagbot

BAG = str(ROOT / "bags" / "design2_n2_steps.mcap")


def refused(p, line: str) -> None:
    assert p.returncode == 2, (p.returncode, p.stdout, p.stderr)
    assert p.stderr == line + "\n", p.stderr
    assert p.stdout == "", p.stdout          # no summary, no 'wrote', no table: the work never started


@pytest.mark.parametrize("argv, option", [
    (["render", "design1", "--out", "{missing}/x.png"], "--out"),
    (["render", "design1", "--out", "{tmp}/x.png", "--gif", "{missing}/a.gif"], "--gif"),
    (["render", BAG, "--out", "{missing}/x.svg"], "--out"),
    (["bag-summary", BAG, "--plot", "{missing}/x.png"], "--plot"),
    (["bag-recover", BAG, "-o", "{missing}/r.mcap"], "--output"),
    (["demo", "--record", "{missing}/run.mcap"], "--record"),
])
def test_a_file_in_a_missing_directory_is_refused_before_any_work(tmp_path, argv, option):
    missing = tmp_path / "missing_dir"
    argv = [a.format(missing=missing, tmp=tmp_path) for a in argv]
    path = argv[argv.index(option if option in argv else "-o") + 1]
    p = flagbot(*argv, timeout=300)
    refused(p, f"error: {option} {path}: directory {missing} does not exist")
    assert not missing.exists() and list(tmp_path.iterdir()) == []      # nothing created, not even the figure


def test_a_directory_or_a_wrong_suffix_is_refused_for_a_figure(tmp_path):
    refused(flagbot("render", "design1", "--out", str(tmp_path)),
            f"error: --out {tmp_path}: is a directory; give a file name, e.g. {tmp_path / 'name'}")
    refused(flagbot("bag-summary", BAG, "--plot", str(tmp_path / "plot.bmp")),
            f"error: --plot {tmp_path / 'plot.bmp'}: matplotlib cannot write .bmp figures; the suffix names the "
            "format: " + ", ".join("." + k for k in sorted(_figure_kinds())))
    refused(flagbot("render", "design1", "--out", str(tmp_path / "fig.png"), "--gif", str(tmp_path / "anim.png")),
            f"error: --gif {tmp_path / 'anim.png'}: the animation is a GIF; give a file name ending in .gif")
    refused(flagbot("bag-recover", BAG, "-o", str(tmp_path)),
            f"error: --output {tmp_path}: is a directory; give a file name, e.g. {tmp_path / 'name'}")
    assert list(tmp_path.iterdir()) == []


def test_the_directory_options_are_refused_when_a_file_is_there(tmp_path):
    taken = tmp_path / "taken"
    taken.write_text("keep me")
    refused(flagbot("demo", "--log-dir", str(taken)), f"error: --log-dir {taken}: exists and is not a directory")
    refused(flagbot("bench", "accuracy", "--quick", "--out", str(taken)),
            f"error: --out {taken}: exists and is not a directory")
    assert taken.read_text() == "keep me"


def test_the_pyelastica_benchmark_checks_its_json_file_first(tmp_path):
    p = subprocess.run([sys.executable, "-m", "flagbot_sim.bench.pyelastica", "--quick", "--json",
                        str(tmp_path / "no" / "out.json")], capture_output=True, text=True, cwd=ROOT, timeout=120,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    refused(p, f"error: --json {tmp_path / 'no' / 'out.json'}: directory {tmp_path / 'no'} does not exist")


def _figure_kinds():
    from matplotlib.backend_bases import FigureCanvasBase
    return FigureCanvasBase.get_supported_filetypes()


def test_the_checks_leave_no_file_behind_and_keep_an_existing_one(tmp_path):
    new = tmp_path / "new.png"
    assert check_figure_file(new, "--out") == new and not new.exists()       # the probe file is removed
    old = tmp_path / "old.png"
    old.write_bytes(b"previous figure")
    assert check_out_file(old, "--out") == old and old.read_bytes() == b"previous figure"
    with pytest.raises(SceneError, match=r"^--plot: the file name is empty$"):
        check_out_file("", "--plot")
    with pytest.raises(SceneError, match=r"is not a directory$"):
        check_out_file(old / "x.png", "--out")                  # the 'directory' is a file
    with pytest.raises(SceneError, match="has no suffix"):
        check_figure_file(tmp_path / "figure", "--out")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(SceneError, match="exists and is not a regular file"):
        check_out_file(fifo, "--out")                         # (opening it would block)
    assert make_out_dir(tmp_path / "a" / "b", "--log-dir").is_dir()


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into a read-only directory")
def test_a_directory_without_write_permission_is_refused(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(SceneError, match=r"cannot write it: Permission denied"):
            check_out_file(ro / "x.png", "--out")
    finally:
        ro.chmod(0o755)
