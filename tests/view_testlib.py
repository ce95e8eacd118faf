"""What the live view's tests share: a stepped simulation to show, and the view publishing it from a thread."""
from __future__ import annotations

import threading
import time

from flagbot_sim.physics import Simulation
from flagbot_sim.scene import load_scene


def stepped_design2(n_flagella: int = 3, steps: int = 4) -> Simulation:
    """Design 2 with ``n_flagella`` after ``steps`` steps (the head has turned: nothing is at its rest value)."""
    s = Simulation(load_scene("design2", [f"robot.n_flagella={n_flagella}"]))
    for _ in range(steps):
        s.step()
    return s


class Publishing:
    """``view`` publishing ``sim`` every 50 ms from a thread inside the ``with`` block. ``sim`` is not stepped:
    every publication shows the same instant, so what a client decodes can be compared with ``sim`` exactly."""

    def __init__(self, view, sim):
        self.view, self.sim = view, sim
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.view.update(self.sim, force=True)
            time.sleep(0.05)

    def __enter__(self) -> "Publishing":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
