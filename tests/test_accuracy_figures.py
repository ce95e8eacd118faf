"""The accuracy study's figures, redrawn from the shipped docs/accuracy.csv: panels titled by what they show, the
presets' names at their runs without covering one another, and the CSV read back exactly as it was written."""
import csv
import io
import math

import pytest
from PIL import Image

from flagbot_sim.bench import accuracy as A
from flagbot_sim.cli import main
from cli_helpers import ROOT
from figure_checks import label_boxes, overlapping

CSV = ROOT / "docs" / "accuracy.csv"


@pytest.fixture(scope="module")
def runs():
    return A.read_csv(CSV)


def test_read_csv_gives_back_the_rows_it_was_written_from(runs, tmp_path):
    out = tmp_path / "again.csv"
    A.write_csv(out, runs, A.References(None))
    shipped = [r for r in csv.reader(io.StringIO(CSV.read_text())) if not r[0].startswith("reference:")]
    assert list(csv.reader(io.StringIO(out.read_text()))) == shipped
    assert {r.part for r in runs} == {"front", "calibration", "presets"}


def test_the_front_is_titled_by_what_each_panel_shows_and_its_names_do_not_overlap(runs):
    front = [r for r in runs if r.part == "front"]
    fig = A.front_figure(front)
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles == [A.CASE_TITLES[c] for c in dict.fromkeys(r.case for r in front)]
    assert not any(c in t for t in titles for c in A.CASES)          # no internal case name (design1_n2, ...)
    assert overlapping(label_boxes(fig)) == []
    # every run with a preset's discretisation is named, the name's leader pointing at that run
    for k, ax in enumerate(fig.axes):
        key = "max_time_err" if k < len(titles) else "max_total_err"
        case = list(dict.fromkeys(r.case for r in front))[k % len(titles)]
        want = sorted((A._preset_tag(r), r.wall, getattr(r, key)) for r in front
                      if r.case == case and A._preset_tag(r) and math.isfinite(getattr(r, key)))
        got = sorted((t.get_text(), *t.xy) for t in ax.texts)
        assert got == want and {w[0] for w in want} >= {"paper", "default"}


def test_the_calibration_names_its_integrators_and_cases(runs):
    fig = A.calibration_figure([r for r in runs if r.part == "calibration"])
    assert [ax.get_title() for ax in fig.axes] == ["BDF2: achieved time error / requested rtol",
                                                   "implicit Euler: achieved time error / requested rtol"]
    labels = [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
    assert "rtol 0.01, design 1: clamped flagellum" in labels and not any("clamped1" in t for t in labels)
    assert overlapping(label_boxes(fig)) == []


def test_plot_from_redraws_the_figures_without_running(tmp_path, capsys):
    assert main(["bench", "accuracy", "--plot-from", str(CSV), "--out", str(tmp_path)]) == 0
    for name in ("accuracy_vs_time.png", "accuracy_calibration.png"):
        with Image.open(tmp_path / name) as im:
            assert im.format == "PNG" and im.size[0] > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["accuracy_calibration.png", "accuracy_vs_time.png"]
    assert main(["bench", "accuracy", "--plot-from", str(tmp_path / "none.csv"), "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: --plot-from ")
