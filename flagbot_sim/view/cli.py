"""The live view on the command line: ``flagbot run SCENE --view`` (:class:`RunView`) and the server start shared
with ``flagbot replay BAG --view`` (:func:`flagbot_sim.commands.replay.cmd_replay_view`), both driven by the
commands (:mod:`flagbot_sim.commands`), which this module does not import. The options themselves are in
:mod:`.args`. Nothing here imports the live view (or foxglove) at load time: building ``flagbot``'s parser or a
run without ``--view`` does not cost it (~0.03 s).
"""
from __future__ import annotations

import sys
import time


def open_live_view(args):
    """The LiveView the arguments ask for (``--view``), or None. A taken port ends the command with a one-line
    error (exit 1); a missing ``[view]`` extra raises MissingExtra, which the command's entry point reports with
    the exit code of every missing extra (:data:`flagbot_sim.optional.EXIT_CODE`)."""
    if not getattr(args, "view", False):
        return None
    from .live import LAYOUT_FILE, LiveView, ViewError
    try:
        view = LiveView(host=args.view_host, port=args.view_port)
    except ViewError as exc:
        raise SystemExit(f"error: {exc}") from None
    print(f"live view: {view.url} (Foxglove app: Open connection -> Foxglove WebSocket; layout: Layouts -> Import "
          f"from file -> {LAYOUT_FILE})", file=sys.stderr, flush=True)
    return view


def wait_for_client(view, seconds: float) -> bool:
    """Wait up to ``seconds`` (wall) until a client subscribes to one of the view's channels; True if one did."""
    end = time.monotonic() + max(0.0, seconds)
    while not view.has_clients():
        if time.monotonic() >= end:
            return False
        time.sleep(0.02)
    return True


def no_subscriber_note(seconds: float, then: str) -> str:
    """What ``--view-wait`` says when it ran out: it waits for a subscription, not a connection (the SDK's server
    does not report connections: an app that is connected but shows none of the channels is not seen)."""
    from .live import TOPICS
    return (f"live view: no client subscribed to {', '.join(TOPICS)} within {seconds:g} s (a connected app "
            f"counts once one of its panels shows one of them); {then} anyway")


def wait_or_note(view, seconds: float, then: str) -> bool:
    """``--view-wait``: wait up to ``seconds`` for a subscriber; print :func:`no_subscriber_note` if none came."""
    if seconds > 0 and not wait_for_client(view, seconds):
        print(no_subscriber_note(seconds, then), file=sys.stderr, flush=True)
        return False
    return True


class RunView:
    """``flagbot run --view``: publish the run to a :class:`~.live.LiveView` as it goes, paced to be watchable.

    :meth:`tick` is the run's per-step callback: the view's own rate limit makes it cheap, and with
    ``rtf > 0`` it sleeps so that simulated time advances at ``rtf`` times wall time."""

    def __init__(self, view, rtf: float = 1.0, wait: float = 0.0):
        if not (rtf >= 0):
            raise SystemExit(f"error: --view-rtf must be >= 0 (0 = as fast as possible), got {rtf}")
        self.view = view
        self.rtf = float(rtf)
        self.wait = float(wait)
        self._wall0 = self._t0 = None

    @classmethod
    def from_args(cls, args) -> "RunView | None":
        view = open_live_view(args)
        return None if view is None else cls(view, rtf=args.view_rtf, wait=args.view_wait)

    def start(self, sim) -> None:
        wait_or_note(self.view, self.wait, "running")
        self.view.update(sim, force=True)
        self._wall0, self._t0 = time.monotonic(), sim.time

    def tick(self, sim) -> None:
        self.view.update(sim)
        if self.rtf > 0 and self._wall0 is not None:
            ahead = self._wall0 + (sim.time - self._t0) / self.rtf - time.monotonic()
            if ahead > 0:
                time.sleep(ahead)

    def close(self, sim=None) -> None:
        if sim is not None:
            self.view.update(sim, force=True)       # the final state, whatever the rate limit
        self.view.close()
