"""Play a recording into the Foxglove live view with its recorded timing (``flagbot replay BAG --view``, whose
command is :func:`flagbot_sim.commands.replay.cmd_replay_view`).

No ROS is needed (the file is decoded by flagbot_sim.bag). ``--rate``, ``--loop`` and ``--start-offset`` mean what
they mean for the ROS replay; the view shows at most its ``max_rate`` frames per second of wall time, skipping
frames in between (the last one is always shown).
"""
from __future__ import annotations

import threading
import time

from .recorded import RecordedRun


def play(run: RecordedRun, view, *, rate: float = 1.0, loop: bool = False, start_offset: float = 0.0,
         stop: threading.Event | None = None) -> int:
    """Publish ``run``'s frames to ``view`` at ``rate`` times their recorded pace; the number sent to a client."""
    if not rate > 0:
        raise ValueError(f"--rate must be > 0, got {rate}")
    stop = stop or threading.Event()
    frames = [f for f in run.frames if f.t >= run.frames[0].t + start_offset]
    if not frames:
        raise ValueError(f"start offset {start_offset} s is past the recording's end "
                         f"({run.frames[-1].t - run.frames[0].t:.3f} s)")
    shown = 0
    while True:
        wall0, t0 = time.monotonic(), frames[0].t
        for k, f in enumerate(frames):
            delay = wall0 + (f.t - t0) / rate - time.monotonic()
            if delay > 0 and stop.wait(delay):
                return shown
            shown += view.publish(f, force=(k == 0 or k == len(frames) - 1))
        if not loop or stop.is_set():
            return shown
