"""Benchmarks: `flagbot bench accuracy` (accuracy vs time study) and `flagbot bench speed` (throughput)."""


def register(sub) -> None:
    from . import accuracy, speed
    p = sub.add_parser("bench", help="benchmarks: accuracy vs time, throughput")
    bsub = p.add_subparsers(dest="bench", required=True)
    a = bsub.add_parser("accuracy", help="error of the steady outputs vs wall time over a grid of dt x edge length")
    accuracy.add_arguments(a)
    a.set_defaults(func=accuracy.run)
    s = bsub.add_parser("speed", help="steps/s, real-time factor, per-phase breakdown, cost vs DOF, PyElastica")
    speed.add_arguments(s)
    s.set_defaults(func=speed.run)
