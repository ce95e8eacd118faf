#!/usr/bin/env python3
"""Throughput benchmark; the same as `python -m flagbot_sim bench speed` (see flagbot_sim/bench/speed.py)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flagbot_sim.bench.speed import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
