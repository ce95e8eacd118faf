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
