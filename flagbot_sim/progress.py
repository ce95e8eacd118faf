"""A dependency-free progress bar for long runs (stderr, redrawn in place, with rate and ETA)."""
from __future__ import annotations

import sys
import time


class ProgressBar:
    def __init__(self, total: float, label: str = "", unit: str = "s", stream=None, enabled: bool = True,
                 min_interval: float = 0.2):
        self.total = float(total)
        self.label = label
        self.unit = unit
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.min_interval = min_interval
        self.t0 = time.perf_counter()
        self._last = 0.0
        self.value = 0.0

    def update(self, value: float, extra: str = "", force: bool = False) -> None:
        self.value = value
        if not self.enabled:
            return
        now = time.perf_counter()
        if not force and now - self._last < self.min_interval:
            return
        self._last = now
        frac = min(1.0, value / self.total) if self.total > 0 else 1.0
        width = 28
        fill = int(round(frac * width))
        elapsed = now - self.t0
        eta = elapsed * (1.0 - frac) / frac if frac > 0 else float("nan")
        line = (f"\r{self.label} [{'#' * fill}{'.' * (width - fill)}] {100 * frac:5.1f}% "
                f"{value:.4g}/{self.total:.4g} {self.unit}  elapsed {elapsed:5.1f}s  eta {eta:5.1f}s  {extra}")
        self.stream.write(line[:160].ljust(100))
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.update(self.value, force=True)
            self.stream.write("\n")
            self.stream.flush()
