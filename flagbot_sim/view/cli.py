"""The live view on the command line: ``flagbot run SCENE --view`` (:class:`RunView`) and the server start shared
with ``flagbot replay BAG --view`` (:mod:`.replay`). The options themselves are in :mod:`.args`; ``flagbot render``
is registered by :mod:`.render`. Nothing here imports foxglove at load time: building ``flagbot``'s parser does not
cost it.
"""
from __future__ import annotations

import sys
import time

from .live import LAYOUT_FILE


def open_live_view(args):
    """The LiveView the arguments ask for (``--view``), or None; a missing extra or a taken port ends the command
    with a one-line error (exit 1)."""
    if not getattr(args, "view", False):
        return None
    from ..optional import MissingExtra
    from .live import LiveView, ViewError
    try:
        view = LiveView(host=args.view_host, port=args.view_port)
    except (MissingExtra, ViewError) as exc:
        raise SystemExit(f"error: {exc}") from None
    print(f"live view: {view.url} (Foxglove app: Open connection -> Foxglove WebSocket; layout: Layouts -> Import "
          f"from file -> {LAYOUT_FILE})", file=sys.stderr, flush=True)
    return view


def wait_for_client(view, seconds: float) -> bool:
    """Wait up to ``seconds`` (wall) until a client subscribes; True if one did."""
    end = time.monotonic() + max(0.0, seconds)
    while not view.has_clients():
        if time.monotonic() >= end:
            return False
        time.sleep(0.02)
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
        if self.wait > 0 and not wait_for_client(self.view, self.wait):
            print(f"live view: no client after {self.wait:g} s; running anyway", file=sys.stderr, flush=True)
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
