#!/usr/bin/env python3
"""sim_node under a cmd_omega flood; the same as `flagbot bench flood` (see flagbot_sim/bench/flood.py)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flagbot_sim.bench.flood import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
