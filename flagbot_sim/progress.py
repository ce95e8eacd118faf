"""A dependency-free progress display for long runs, on stderr.

On a terminal it is one line redrawn in place (``\\r``), cut to the terminal's width (re-read at every redraw,
so a resized window is followed) and padded over whatever the previous, longer line left. Anywhere else (a
pipe, a log file, CI) it writes plain lines, no ``\\r``: one at the first update, then one every
``log_interval`` seconds of wall time, and the last one on :meth:`ProgressBar.close`.

The ETA is the remaining amount at the rate measured since the first update (so a slow first step, e.g. the
kernels compiling, does not inflate it), and is shown only once it means something: after ``eta_after``
seconds and some progress since then. It never reads 'nan'; beyond 100 hours it reads '>99h'.
"""
from __future__ import annotations

import math
import os
import shutil
import sys
import time

BAR_MIN, BAR_MAX = 10, 28


def format_duration(seconds: float) -> str:
    """'42s', '3m05s', '2h07m'; '>99h' beyond a hundred hours."""
    if not math.isfinite(seconds) or seconds >= 100 * 3600:
        return ">99h"
    s = int(round(max(0.0, seconds)))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{(s % 3600) // 60:02d}m"


def _number(x: float) -> str:
    return f"{x:.4g}" if math.isfinite(x) else "--"


def terminal_columns(stream) -> int:
    """Columns of the terminal ``stream`` writes to: $COLUMNS if set, else the tty's size, else 80."""
    env = os.environ.get("COLUMNS", "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    try:
        return os.get_terminal_size(stream.fileno()).columns or 80
    except (AttributeError, OSError, ValueError):
        return shutil.get_terminal_size((80, 24)).columns


def is_terminal(stream) -> bool:
    """Whether ``stream`` is a terminal (a line may be redrawn in place), False for anything that cannot say."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _draw_in_place(stream, line_for_width, drawn_width: int) -> int:
    """Redraw the terminal line: ``line_for_width(width)`` is the text for the terminal's width, padded over what
    the previous, longer line left (``drawn_width``, its length). Returns the new line's length."""
    # one column short of the edge: writing the last column makes some terminals wrap
    width = max(1, terminal_columns(stream) - 1)
    line = line_for_width(width)
    pad = " " * max(0, min(drawn_width, width) - len(line))
    stream.write("\r" + line + pad)
    return len(line)


class ProgressBar:
    def __init__(self, total: float, label: str = "", unit: str = "s", stream=None, enabled: bool = True,
                 min_interval: float = 0.2, log_interval: float = 10.0, eta_after: float = 1.0,
                 tty: bool | None = None, clock=time.perf_counter):
        self.total = float(total)
        self.label = label
        self.unit = unit
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = is_terminal(self.stream) if tty is None else tty
        self.min_interval = min_interval if self.tty else log_interval
        self.eta_after = eta_after
        self.clock = clock
        self.t0 = clock()
        self.value = 0.0
        self.extra = ""
        self._extra_fn = None
        self._first: tuple[float, float] | None = None       # (time, value) of the first update
        self._last_draw = -math.inf
        self._drawn_value: float | None = None
        self._drawn_width = 0                                  # length of the line now on the terminal

    # ---------------------------------------------------------------- numbers
    def fraction(self) -> float:
        if not (self.total > 0 and math.isfinite(self.total)):
            return 1.0
        if not math.isfinite(self.value):
            return 0.0
        return min(1.0, max(0.0, self.value / self.total))

    def eta(self, now: float) -> float | None:
        """Seconds left at the rate seen since the first update, or None while that rate means nothing."""
        if self._first is None:
            return None
        t1, v1 = self._first
        done = self.value - v1
        if now - t1 < self.eta_after or not done > 0 or not math.isfinite(self.value):
            return None
        return max(0.0, (self.total - self.value) * (now - t1) / done)

    # ---------------------------------------------------------------- text
    def text(self, now: float, width: int | None = None) -> str:
        """The status line, cut to ``width`` characters if given (the bar shrinks first, then the extra text)."""
        frac = self.fraction()
        eta = self.eta(now)
        head = f"{self.label} " if self.label else ""
        nums = (f" {100 * frac:5.1f}% {_number(self.value)}/{_number(self.total)} {self.unit}"
                f"  elapsed {format_duration(now - self.t0)}")
        if eta is not None and frac < 1.0:
            nums += f"  eta {format_duration(eta)}"
        extra = f"  {self.extra}" if self.extra else ""
        bar_width = BAR_MAX
        if width is not None:
            room = width - len(head) - len(nums) - len(extra) - 2
            bar_width = max(BAR_MIN, min(BAR_MAX, room))
        fill = int(round(frac * bar_width))
        line = f"{head}[{'#' * fill}{'.' * (bar_width - fill)}]{nums}{extra}"
        if width is not None and len(line) > width:
            line = line[:max(0, width - 3)] + "..." if width > 3 else line[:width]
        return line

    # ---------------------------------------------------------------- drawing
    def update(self, value: float, extra="", force: bool = False) -> None:
        """``extra``: the text after the bar, or a function returning it, called only when the bar is drawn (a
        caller updating every few steps then pays for formatting a few times a second, not every time)."""
        now = self.clock()
        self.value = float(value)
        if callable(extra):
            self._extra_fn = extra
        elif extra:
            self._extra_fn = None
            self.extra = " ".join(str(extra).split())          # one line, whatever the caller passed
        first = self._first is None
        if first:
            self._first = (now, self.value)
        if not self.enabled:
            return
        if not (force or first) and now - self._last_draw < self.min_interval:
            return
        self._draw(now)

    def _draw(self, now: float) -> None:
        if self._extra_fn is not None:
            self.extra = " ".join(str(self._extra_fn()).split())
        self._last_draw = now
        self._drawn_value = self.value
        if self.tty:
            self._drawn_width = _draw_in_place(self.stream, lambda width: self.text(now, width), self._drawn_width)
        else:
            self.stream.write(self.text(now) + "\n")
        self.stream.flush()

    def note(self, line: str) -> None:
        """Write ``line`` (a warning) on a line of its own; on a terminal over the bar, which is redrawn below it
        at the next update."""
        if self.tty and self.enabled and self._drawn_width:
            self.stream.write("\r" + line.ljust(self._drawn_width) + "\n")
            self._drawn_width = 0
            self._last_draw = -math.inf
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if not self.enabled:
            return
        if self.tty:
            self._draw(self.clock())
            self.stream.write("\n")
            self.stream.flush()
            self._drawn_width = 0
        elif self._drawn_value != self.value or self._first is None:
            self._draw(self.clock())


class StatusLine:
    """What is being waited for, with the elapsed time, when there is no total to show a bar of (the kernels
    compiling, nodes starting): ``update("sim_node: compiling kernels")`` shows ``sim_node: compiling kernels
    [12s]``. On a terminal the line is redrawn in place (at most every ``min_interval``, or at once when the text
    changes); anywhere else a plain line is written when the text changes and every ``log_interval`` seconds, so
    a log shows what was waited for and that it was still going."""

    def __init__(self, stream=None, enabled: bool = True, min_interval: float = 0.5, log_interval: float = 15.0,
                 tty: bool | None = None, clock=time.monotonic):
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = is_terminal(self.stream) if tty is None else tty
        self.min_interval = min_interval if self.tty else log_interval
        self.clock = clock
        self.t0 = clock()
        self.text = ""
        self._last_draw = -math.inf
        self._drawn_text: str | None = None
        self._drawn_width = 0

    def elapsed(self) -> float:
        return self.clock() - self.t0

    def line(self, width: int | None = None) -> str:
        line = f"{self.text} [{format_duration(self.elapsed())}]"
        if width is not None and len(line) > width:
            line = line[:max(0, width - 3)] + "..." if width > 3 else line[:width]
        return line

    def update(self, text: str) -> None:
        self.text = " ".join(str(text).split())
        if not self.enabled:
            return
        now = self.clock()
        if self.text == self._drawn_text and now - self._last_draw < self.min_interval:
            return
        self._last_draw = now
        self._drawn_text = self.text
        if self.tty:
            self._drawn_width = _draw_in_place(self.stream, self.line, self._drawn_width)
        else:
            self.stream.write(self.line() + "\n")
        self.stream.flush()

    def close(self, final: str | None = None) -> None:
        """End the status: ``final`` (e.g. 'kernels compiled in 18.2 s') replaces it, else a terminal's line is
        cleared and a log keeps its last line."""
        if not self.enabled:
            return
        if self.tty:
            if final is not None:
                _draw_in_place(self.stream, lambda width: final, self._drawn_width)
                self.stream.write("\n")
            elif self._drawn_width:
                self.stream.write("\r" + " " * self._drawn_width + "\r")
            self._drawn_width = 0
        elif final is not None:
            self.stream.write(final + "\n")
        self.stream.flush()
