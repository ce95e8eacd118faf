"""``flagbot render``: the paper's Fig. 1 drawn from the state, to scale.

The checks read the matplotlib artists (the data the figure was drawn from), not pixels: the plotted flagellum
tips are the tips of an independent run of the same scene (or the recorded markers), the head disc is the head's
position and radius, a flagellum's stroke is its true diameter on the panels' scale, the 2 cm bar is 2 cm on that
scale. The written files are read back by Pillow (an independent reader) for their pixel size and frame count.
"""
import math

import numpy as np
import pytest
from PIL import Image

from flagbot_sim import cli, world
from flagbot_sim.bag import BagReader
from flagbot_sim.physics import Simulation
from flagbot_sim.scene import load_scene
from flagbot_sim.view import render
from flagbot_sim.view.render import figure, project, recorded_row, simulate_row
from cli_helpers import ROOT

SAMPLE = ROOT / "bags" / "design2_n2_steps.mcap"


def artists(ax, gid):
    return [a for a in list(ax.lines) + list(ax.patches) if a.get_gid() == gid]


def points_per_metre(ax) -> tuple[float, float]:
    """Display points per data metre along x and along y (equal aspect: the same)."""
    d = ax.transData.transform([[0.0, 0.0], [1.0, 1.0]]) - ax.transData.transform([[0.0, 0.0], [0.0, 0.0]])
    dpi = ax.figure.dpi
    return d[1, 0] * 72.0 / dpi, d[1, 1] * 72.0 / dpi


def check_drawn(fig, rows, expected_tips, scene_sizes):
    """Every panel: the tips drawn where ``expected_tips[row][col]`` (n, 3 world) says, strokes of the true width,
    the head disc of the true radius at the head centre; every panel on one scale."""
    fig.draw_without_rendering()            # lay the axes out as saving would
    scales = set()
    for ri, ci, ax_side, ax_end in fig.flagbot_axes:
        g = rows[ri].snapshots[ci]
        r0, R_h = scene_sizes[ri]
        for ax, view in ((ax_side, "side"), (ax_end, "end")):
            sx, sy = points_per_metre(ax)
            assert sx == pytest.approx(sy, rel=1e-9), "equal aspect: drawn to scale"
            scales.add(round(sx, 6))
            for i, tip in enumerate(expected_tips[ri][ci]):
                (line,) = artists(ax, f"flagellum/{i}")
                np.testing.assert_allclose([line.get_xdata()[-1], line.get_ydata()[-1]], project(tip, view)[0],
                                           rtol=0, atol=1e-12)
                assert line.get_linewidth() == pytest.approx(2 * r0 * sx, rel=1e-9), "the true diameter"
            (head,) = artists(ax, "head")
            assert head.get_radius() == R_h
            np.testing.assert_allclose(head.center, project(g.head_centre, view)[0], rtol=0, atol=1e-15)
    assert len(scales) == 1, f"all panels on one scale, got {scales}"
    (bar,) = [a for ax in fig.axes for a in ax.lines if a.get_gid() == "scalebar"]
    x = bar.get_xdata()
    assert x[1] - x[0] == pytest.approx(0.02)
    bx, _ = points_per_metre(bar.axes)
    assert bx == pytest.approx(scales.pop(), rel=1e-6), "the 2 cm bar is on the panels' scale"


def test_simulated_rows_draw_the_simulated_state_to_scale(tmp_path):
    times = [0.05, 0.12, 0.2]
    rows, tips, sizes = [], [], []
    for n in (2, 3):
        scene = load_scene("design2", [f"robot.n_flagella={n}"])
        rows.append(simulate_row(scene, times=times, frames=4))
        # an independent run of the same scene: its tips at the same steps, turned into the world frame
        sim = Simulation(scene)
        row_tips = []
        for t in times:
            while sim.time < t - 0.5 * scene.time.dt:
                sim.step()
            row_tips.append(world.to_world(np.array([c[-1] for c in sim.flagella_centrelines()]),
                                           sim.observer.origin))
        tips.append(row_tips)
        sizes.append((scene.flagellum.radius, scene.head.radius))
    assert [len(g.flagella) for g in rows[1].snapshots] == [3, 3, 3]
    assert [g.t for g in rows[0].snapshots] == pytest.approx(times)
    fig = figure(rows, title="test", width=12.0, dpi=80)
    check_drawn(fig, rows, tips, sizes)
    out = tmp_path / "fig.png"
    fig.savefig(out, dpi=80)
    w, h = fig.get_size_inches()
    with Image.open(out) as im:
        assert im.format == "PNG" and im.size == (int(12.0 * 80), int(h * 80))   # Agg truncates
    # the animation of the same window: Pillow reads every frame back
    gif = tmp_path / "fig.gif"
    assert render.animation(rows, gif, fps=5, dpi=50) == 4
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames == 4


def test_default_times_span_one_flagellar_revolution_once_steady():
    t = render.revolution_times(10.0, 2.0, 5)
    assert t == pytest.approx([10.0 + k * (2 * math.pi / 2.0) / 5 for k in range(5)])
    assert render.revolution_times(0.0, -2.0, 4) == pytest.approx([0, math.pi / 4, math.pi / 2, 3 * math.pi / 4])


def test_render_command_from_a_recording_draws_the_recorded_markers(tmp_path, capsys):
    out = tmp_path / "bag.png"
    assert cli.main(["render", str(SAMPLE), "--times", "4,6.05,15.9", "--out", str(out), "--dpi", "60"]) == 0
    with Image.open(out) as im:
        assert im.size[0] == 16 * 60
        assert f"{im.size[0]} x {im.size[1]} px" in capsys.readouterr().out     # the size it reports is the file's
    row = recorded_row(SAMPLE, times=[4, 6.05, 15.9])
    fig = figure([row], width=16, dpi=60)
    # independently: the recorded MarkerArray at the nearest stamp, its flagellum points as recorded
    with BagReader(SAMPLE) as r:
        rows = r.decoded("/markers")
        meta_scene = load_scene("design2")
    stamps = np.array([m.markers[0].header.stamp.sec + 1e-9 * m.markers[0].header.stamp.nanosec
                       for _, _, m in rows])
    tips = []
    for t in (4, 6.05, 15.9):
        m = rows[int(np.argmin(np.abs(stamps - t)))][2]
        flag = [mk for mk in m.markers if mk.ns == "flagella"]
        tips.append([[mk.points[-1].x, mk.points[-1].y, mk.points[-1].z] for mk in flag])
    assert [g.t for g in row.snapshots] == pytest.approx([4.0, 6.06, 15.9], abs=0.051)
    check_drawn(fig, [row], [tips], [(meta_scene.flagellum.radius, meta_scene.head.radius)])
    # the caption quotes the recorded command step's steady values (bag-summary's)
    assert row.values["omega_T"] == pytest.approx(100 * 2 * math.pi / 60)
    assert 0 < row.values["omega_h"] < row.values["omega_T"] and row.values["v"] > 0


@pytest.mark.parametrize("argv, message", [
    (["--times", "1,x"], "--times must be a comma list of numbers"),
    (["--times", "400"], "outside the recording"),
    (["--snapshots", "0"], "--snapshots must be >= 1"),
])
def test_bad_render_arguments_are_refused_with_a_reason(tmp_path, capsys, argv, message):
    assert cli.main(["render", str(SAMPLE), "--out", str(tmp_path / "x.png"), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.startswith("error: ") and err.count("\n") == 1
    assert not (tmp_path / "x.png").exists()


# ------------------------------------------------------------------------------------------------ the paper's layout
def test_the_paper_layout_has_a_row_per_design_with_both_n_in_each_panel(tmp_path):
    """Paper Fig. 1: row (a) is design 1, row (b) design 2, panels (a1), (a2), ... each with the side views of
    n = 2 and n = 3 at one time, drawn from the simulated state to one scale; no label on another, on a panel,
    or off the figure."""
    from figure_checks import label_boxes, outside_figure, overlapping
    times = [0.05, 0.12]
    rows, radii = [], {}
    for name in ("design1", "design2"):
        for n in (2, 3):
            scene = load_scene(name, [f"robot.n_flagella={n}"])
            rows.append(simulate_row(scene, times=times))
            radii[name] = (scene.head.radius, scene.flagellum.radius)
    assert [r.group for r in rows] == ["design1", "design1", "design2", "design2"]
    fig = render.paper_figure(rows, title="test", width=12.0, dpi=80)
    fig.draw_without_rendering()
    by_group = {0: rows[:2], 1: rows[2:]}
    seen = set()
    scales = set()
    for gi, ri, ci, ax in fig.flagbot_panels:
        g = by_group[gi][ri].snapshots[ci]
        R_h, r0 = radii[("design1", "design2")[gi]]
        (head,) = artists(ax, "head")
        assert head.get_radius() == R_h                          # the row's design, as the paper's caption says
        np.testing.assert_allclose(head.center, project(g.head_centre, "side")[0], rtol=0, atol=1e-15)
        flags = [a for a in ax.lines if (a.get_gid() or "").startswith("flagellum/")]
        assert len(flags) == (2, 3)[ri]                          # n = 2 above n = 3
        for i in range(len(flags)):
            (line,) = artists(ax, f"flagellum/{i}")
            np.testing.assert_allclose([line.get_xdata()[-1], line.get_ydata()[-1]],
                                       project(g.flagella[i][-1], "side")[0], rtol=0, atol=1e-12)
        scales.add(round(points_per_metre(ax)[0], 6))
        seen.add((gi, ri, ci))
    assert seen == {(gi, ri, ci) for gi in (0, 1) for ri in (0, 1) for ci in (0, 1)}
    assert len(scales) == 1, "every panel on one scale"
    titles = {(gi, ci): ax.get_title(loc="left") for gi, ri, ci, ax in fig.flagbot_panels if ri == 0}
    assert titles == {(0, 0): "(a1)  t = 0.05 s", (0, 1): "(a2)  t = 0.12 s",
                      (1, 0): "(b1)  t = 0.05 s", (1, 1): "(b2)  t = 0.12 s"}
    headers = [t.get_text() for t in fig.texts if t.get_text().startswith(("(a)", "(b)"))]
    assert headers[0].startswith("(a)  design 1") and headers[1].startswith("(b)  design 2")
    boxes = label_boxes(fig)
    r = render_of(fig)
    panels = [(f"panel {gi}{ri}{ci}", ax.get_window_extent(r)) for gi, ri, ci, ax in fig.flagbot_panels]
    assert overlapping(boxes + panels) == [] and outside_figure(fig, boxes) == []


def render_of(fig):
    from flagbot_sim.plotlabels import renderer_of
    return renderer_of(fig)


def test_the_per_design_layout_numbers_its_panels_without_the_papers_letters():
    from figure_checks import label_boxes, outside_figure, overlapping
    scene = load_scene("design2", ["robot.n_flagella=2"])
    rows = [simulate_row(scene, times=[0.05, 0.1]), simulate_row(load_scene("design2"), times=[0.05, 0.1])]
    fig = figure(rows, width=12.0, dpi=80)
    titles = [ax.get_title(loc="left") for _, _, ax, _ in fig.flagbot_axes]
    assert [t.split()[0] for t in titles] == ["(1)", "(2)", "(1)", "(2)"]
    boxes = label_boxes(fig)
    assert overlapping(boxes) == [] and outside_figure(fig, boxes) == []


def test_rows_of_one_design_share_their_times_once_steady(tmp_path, capsys):
    """--layout paper: n = 2 and n = 3 are run up to their steady states side by side, then drawn at the same
    times: from the later steady time, one turn of the slower flagella in --snapshots steps."""
    import argparse
    args = argparse.Namespace(sources=["design2"], overrides=[], n=None, times=None, snapshots=4, duration=None,
                              frames=0, gif=None, namespace=None, layout="paper")
    from flagbot_sim.commands.render import build_rows
    rows, title = build_rows(args)
    t2, t3 = ([g.t for g in r.snapshots] for r in rows)
    assert t2 == t3 and title.startswith("Fig. 1, a row per design: design 2")
    period = max(2 * math.pi / abs(r.values["omega_t"]) for r in rows)
    assert np.diff(t2) == pytest.approx([period / 4] * 3, abs=0.011)     # each taken at the nearest step (dt 0.01 s)
    assert all(r.steady for r in rows)
    assert render.common_times([type("S", (), {"time": 3.0})(), type("S", (), {"time": 5.0})()],
                               [{"omega_t": 2.0}, {"omega_t": -1.0}], 2) == pytest.approx([5.0, 5.0 + math.pi])
    # and the command: a PNG of the paper's layout from two designs
    out = tmp_path / "fig1.png"
    assert cli.main(["render", "design1", "design2", "--layout", "paper", "--times", "0.05,0.1", "--out", str(out),
                     "--dpi", "50"]) == 0
    text = capsys.readouterr().out
    assert "  design 1, n = 3: " in text and "  design 2, n = 2: " in text
    with Image.open(out) as im:
        assert im.format == "PNG" and im.size[0] == 16 * 50
