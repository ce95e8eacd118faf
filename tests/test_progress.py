"""The progress display: redraws in place only on a terminal, plain periodic lines elsewhere, never 'nan', an ETA
only once it means something, always within the terminal's width, nothing stale left on the line."""
import io
import math

import pytest

from flagbot_sim.progress import ProgressBar, format_duration


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


class Terminal(io.StringIO):
    def isatty(self):
        return True


def draws(text: str) -> list[str]:
    """What a terminal shows after each redraw: the segments between carriage returns."""
    return [d for d in text.split("\r") if d]


def test_on_a_terminal_the_line_is_redrawn_in_place_within_the_width(monkeypatch):
    monkeypatch.setenv("COLUMNS", "60")
    clock, term = Clock(), Terminal()
    bar = ProgressBar(20.0, label="design1", stream=term, clock=clock)
    for i in range(1, 41):
        clock.t = 0.25 * i
        bar.update(0.5 * i, "newton 1  w_h +1.234  w_t +0.123 rad/s  v +0.230 mm/s  and much more text here")
    bar.close()
    out = term.getvalue()
    assert out.endswith("\n") and out.count("\n") == 1           # one line, redrawn; a newline only at the end
    segments = draws(out.rstrip("\n"))
    assert len(segments) > 10
    assert all(len(s) <= 59 for s in segments)                  # one column short of the edge
    assert "100.0%" in segments[-1]


def test_a_shorter_redraw_blanks_what_the_longer_one_left(monkeypatch):
    monkeypatch.setenv("COLUMNS", "100")
    clock, term = Clock(), Terminal()
    bar = ProgressBar(10.0, stream=term, clock=clock)
    bar.update(1.0, "x" * 50)
    long_len = len(draws(term.getvalue())[-1])
    clock.t = 1.0
    bar.update(2.0, "short")
    last = draws(term.getvalue())[-1]
    assert len(last) >= long_len and last.rstrip().endswith("short")   # padded over the old text
    assert "x" not in last


def test_a_narrow_terminal_shrinks_the_bar_then_cuts_the_text(monkeypatch):
    for cols in (20, 40, 80, 200):
        monkeypatch.setenv("COLUMNS", str(cols))
        clock, term = Clock(), Terminal()
        bar = ProgressBar(5.0, label="a-long-scene-name", stream=term, clock=clock)
        clock.t = 3.0
        bar.update(2.5, "w_h +1.2345 w_t +0.1234 rad/s v +0.2301 mm/s")
        (seg,) = draws(term.getvalue())
        assert len(seg) <= cols - 1 and seg.startswith("a-long")


def test_off_a_terminal_plain_lines_at_the_log_interval():
    clock, log = Clock(), io.StringIO()                         # a file: isatty() is False
    bar = ProgressBar(100.0, stream=log, clock=clock, log_interval=10.0)
    for i in range(1, 301):                                     # 30 s of wall time, an update every 0.1 s
        clock.t = 0.1 * i
        bar.update(i / 3.0, "newton 1")
    bar.close()
    out = log.getvalue()
    assert "\r" not in out
    lines = out.splitlines()
    # the first update, then one every 10 s of wall time, then the final state
    assert 3 <= len(lines) <= 5 and "100.0%" in lines[-1]
    assert all(ln.startswith("[") for ln in lines)


def test_no_eta_until_it_means_something_and_never_an_absurd_one():
    clock, term = Clock(), Terminal()
    bar = ProgressBar(20.0, stream=term, clock=clock, eta_after=1.0)
    clock.t = 15.0                                              # a slow first step: the kernels compiling
    bar.update(0.01)
    assert "eta" not in bar.text(clock())
    clock.t = 15.5
    bar.update(1.0)
    assert "eta" not in bar.text(clock())                       # too early to tell
    clock.t = 16.0
    bar.update(2.0)
    # 2 s of simulation in 1 s of wall since the first update: 18 s left, not the 150 s that counting the
    # compile time would give
    assert bar.eta(clock()) == pytest.approx(18.0 / 1.99 * 1.0, rel=1e-6)
    assert "eta 9s" in bar.text(clock())
    assert format_duration(81920.0) == "22h45m" and format_duration(1e9) == ">99h"
    assert format_duration(math.nan) == ">99h" and format_duration(125) == "2m05s"


def test_nan_and_infinite_values_never_print_as_nan():
    clock, term = Clock(), Terminal()
    bar = ProgressBar(float("nan"), stream=term, clock=clock)
    bar.update(float("nan"), "w_h --")
    clock.t = 5.0
    bar.update(float("inf"), force=True)
    bar.close()
    assert "nan" not in term.getvalue().lower() and "inf" not in term.getvalue().lower()


def test_disabled_writes_nothing():
    term = Terminal()
    bar = ProgressBar(1.0, stream=term, enabled=False)
    bar.update(0.5, "x")
    bar.close()
    assert term.getvalue() == ""


def test_the_sweep_progress_line_shows_a_failed_point_without_nan():
    from flagbot_sim.commands.sweep import _progress_text
    text = _progress_text({"rows": [{"framework": "der", "error": "no steady state", "hit_cap": False, "n": 2,
                                     "L": 0.111, "omega_T_rpm": 100.0, "v": float("nan"), "wall_seconds": None}]})
    assert "nan" not in text and "v=--mm/s ERROR" in text and "L=111mm" in text


# ------------------------------------------------------------------------------------------------ StatusLine
from flagbot_sim.progress import StatusLine  # noqa: E402


def test_a_status_in_a_log_is_a_line_per_change_and_one_per_interval():
    clock, out = Clock(), io.StringIO()
    st = StatusLine(stream=out, clock=clock, log_interval=15.0)
    st.update("waiting for the nodes: sim_node: starting")
    for t in range(1, 40):                       # same text: a line only every 15 s
        clock.t = float(t)
        st.update("waiting for the nodes: sim_node: starting")
    clock.t = 40.5
    st.update("waiting for the nodes: sim_node: compiling kernels (first run only)")     # changed: at once
    st.close("nodes ready after 41s")
    assert out.getvalue().splitlines() == [
        "waiting for the nodes: sim_node: starting [0s]",
        "waiting for the nodes: sim_node: starting [15s]",
        "waiting for the nodes: sim_node: starting [30s]",
        "waiting for the nodes: sim_node: compiling kernels (first run only) [40s]",
        "nodes ready after 41s"]
    assert "\r" not in out.getvalue()


def test_a_status_on_a_terminal_is_redrawn_in_place_and_cleared_or_replaced(monkeypatch):
    monkeypatch.setenv("COLUMNS", "40")
    clock, term = Clock(), Terminal()
    st = StatusLine(stream=term, clock=clock)
    st.update("compiling kernels (first run only, and a long tail of words)")
    clock.t = 2.0
    st.update("loading")
    segments = draws(term.getvalue())
    assert all(len(s) <= 39 for s in segments) and segments[0].endswith("...")
    assert segments[-1].startswith("loading [2s]") and segments[-1].strip() == "loading [2s]"   # padded over
    st.close()                                   # cleared: what it shows is blanked, the cursor back at the start
    assert term.getvalue().endswith("\r" + " " * len("loading [2s]") + "\r") and "\n" not in term.getvalue()
    st2 = StatusLine(stream=Terminal(), clock=clock)
    st2.update("x")
    st2.close("done in 3 s")
    assert draws(st2.stream.getvalue())[-1] == "done in 3 s\n"
