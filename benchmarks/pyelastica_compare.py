#!/usr/bin/env python3
"""DER vs PyElastica on the clamped flagellum; the same as flagbot_sim/bench/pyelastica.py (see its docstring)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from flagbot_sim.bench.pyelastica import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
