"""``flagbot bench accuracy|speed|memory|startup|flood|steady``: the benchmarks of :mod:`flagbot_sim.bench`, each
loaded only when it runs (registration imports nothing heavy)."""
from __future__ import annotations

from .. import bench


def _run(module: str):
    def run(args):
        import importlib
        return importlib.import_module(f"flagbot_sim.bench.{module}").run(args)
    return run


def register(sub) -> None:
    p = sub.add_parser("bench", help="benchmarks: accuracy vs time, throughput, start-up time")
    bsub = p.add_subparsers(dest="bench", required=True)
    a = bsub.add_parser("accuracy", help="error of the steady outputs vs wall time over a grid of dt x edge length")
    bench.accuracy_arguments(a)
    a.set_defaults(func=_run("accuracy"))
    s = bsub.add_parser("speed", help="steps/s, real-time factor, per-phase breakdown, cost vs DOF, PyElastica")
    bench.speed_arguments(s)
    s.set_defaults(func=_run("speed"))
    m = bsub.add_parser("memory", help="resident memory of a simulation and of sim_node from 1 to 60 simulated minutes")
    m.add_argument("--run-only", action="store_true", help="only the simulation (no ROS)")
    m.add_argument("--node-only", action="store_true", help="only sim_node")
    m.set_defaults(func=_run("memory"))
    t = bsub.add_parser("startup", help="start-up of `flagbot run` as whole processes: cold (empty kernel cache) / "
                                        "warm and warm / `python -c 'import numpy, scipy.sparse, numba'`")
    bench.startup_arguments(t)
    t.set_defaults(func=_run("startup"))
    f = bsub.add_parser("flood", help="sim_node's simulated seconds per wall second and /clock rate under a flood of "
                                      "valid cmd_omega from another process")
    bench.flood_arguments(f)
    f.set_defaults(func=_run("flood"))
    from ..bench import steady as bench_steady          # stdlib imports only
    st = bsub.add_parser("steady", help="flagbot steady vs BDF2 time stepping to the same accuracy, per case; the "
                                        "paper's four sweeps as whole commands against an older checkout (--against)")
    bench_steady.arguments(st)
    st.set_defaults(func=_run("steady"))
