"""``flagbot replay BAG --view``: play a recording into the Foxglove live view, with its recorded timing.

No ROS is needed (the file is decoded by flagbot_sim.bag). ``--rate``, ``--loop`` and ``--start-offset`` mean what
they mean for the ROS replay; the view shows at most its ``max_rate`` frames per second of wall time, skipping
frames in between (the last one is always shown).
"""
from __future__ import annotations

import sys
import threading
import time

from .recorded import RecordedRun, load


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


def cmd_replay_view(args) -> int:
    """``flagbot replay BAG --view [--rate R] [--loop] [--start-offset S] [--view-port P] [--view-wait S]``."""
    from ..bag import BagError
    from ..resim import ResimulationError
    from .cli import open_live_view, wait_or_note
    try:
        run = load(args.bag, args.namespace or None)
    except (BagError, ResimulationError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for n in run.notes:
        print(f"note: {n}", file=sys.stderr)
    view = open_live_view(args)
    try:
        wait_or_note(view, args.view_wait, "playing")
        try:
            shown = play(run, view, rate=args.rate, loop=args.loop, start_offset=args.start_offset)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            shown = None
    finally:
        view.close()
    span = run.frames[-1].t - run.frames[0].t
    sent = "interrupted" if shown is None else f"sent {shown} of {len(run.frames)} frames to the view"
    print(f"{sent} ({run.source}, {span:.3f} s of simulated time)", flush=True)
    return 0
