"""Parameter sweeps over any scene keys: the DER simulator to a detected steady state and the beam balance
(LB, NLB w/o head, NLB) at every grid point, streamed to one tidy CSV, resumable, run serially, on a local
process pool or on a Dask cluster, and the paper's figures drawn from the CSV alone.

    flagbot sweep design1 --grid n=2,3 --grid motor.omega_rpm=20:250:10 --out sweeps/design1
    flagbot sweep-plot sweeps/design1

Layout: ``grid`` (KEY=VALUES parsing and validation), ``task`` (one point, every framework: the unit of work),
``engines`` (serial / local / dask), ``store`` (the directory: manifest, CSV, resume), ``plots`` (figures and
summary from the CSV); the commands ``flagbot sweep`` and ``sweep-plot`` are
:mod:`flagbot_sim.commands.sweep`. See docs/reproduction.md.
"""
from .grid import ALIASES, Point, SweepError, expand, parse_grid, validate
from .task import FRAMEWORKS, SteadySettings, run_point

__all__ = ["ALIASES", "FRAMEWORKS", "Point", "SteadySettings", "SweepError", "expand", "parse_grid", "run_point",
           "validate"]

