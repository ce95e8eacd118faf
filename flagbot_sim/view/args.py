"""The ``--view`` options of ``flagbot run`` and ``flagbot replay``: a leaf module (it imports nothing), so that the
recording tools' argument parser (flagbot_sim/ros/bag_args.py) can offer them without importing the view.
"""
from __future__ import annotations

import argparse

#: default port: the Foxglove app's default for a Foxglove WebSocket connection
DEFAULT_PORT = 8765


def add_view_arguments(p: argparse.ArgumentParser, *, pacing: bool = True) -> None:
    """``--view`` and its options (``flagbot run``; ``flagbot replay`` has its own ``--rate`` so no pacing)."""
    g = p.add_argument_group("live view (Foxglove; needs the [view] extra)")
    g.add_argument("--view", action="store_true",
                   help="serve a live 3-D view and plots to the Foxglove app (Open connection -> Foxglove WebSocket "
                        "-> ws://HOST:PORT)")
    g.add_argument("--view-host", default="127.0.0.1", metavar="HOST",
                   help="interface the view listens on (default 127.0.0.1: this machine only)")
    g.add_argument("--view-port", type=int, default=DEFAULT_PORT, metavar="P",
                   help=f"TCP port of the view (default {DEFAULT_PORT}; 0 = any free port, printed at start)")
    g.add_argument("--view-wait", type=float, default=0.0, metavar="S",
                   help="wait up to S seconds of wall time for a Foxglove client to subscribe before starting")
    if pacing:
        g.add_argument("--view-rtf", type=float, default=1.0, metavar="R",
                       help="with --view, run at R times real time so that it can be watched (default 1; 0 = as fast "
                            "as possible)")
