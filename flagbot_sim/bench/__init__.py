"""Benchmarks: `flagbot bench accuracy` (accuracy vs time study), `flagbot bench speed` (throughput) and
`flagbot bench memory` (resident memory of hour-long runs), `flagbot bench startup` (start-up time of
`flagbot run`, cold and warm, as whole processes) and `flagbot bench flood` (sim_node's pace under a flood of
valid commands from another process).

The options of each benchmark are here (shared by ``flagbot bench X``, registered by
:mod:`flagbot_sim.commands.bench`, and ``python -m flagbot_sim.bench.X``); they import nothing heavy: the simulator
is loaded only when a benchmark actually runs.
"""


def accuracy_arguments(ap) -> None:
    ap.add_argument("--parts", default="front,calibration,presets",
                    help="comma-separated, from front (error vs wall time, implicit Euler and BDF2), calibration "
                         "(requested rtol vs achieved error, 0.5-2000 rpm), presets (each accuracy preset), "
                         "request (accuracy.rtol requested vs achieved vs wall time; not in the default)")
    ap.add_argument("--cases", default="clamped1,clamped2,design1_n2,design1_n3,design2_n2,design2_n3",
                    help="the front's cases, from clamped1, clamped2 (each design's clamped flagellum), design1_n2, "
                         "design1_n3, design2_n2, design2_n3 (the free robot); all at 100 rpm")
    ap.add_argument("--quick", action="store_true", help="3 time steps x 1 edge length, two tolerances, fewer "
                                                         "speeds (about a minute; the whole study ~12 min)")
    ap.add_argument("--repeat", type=int, default=3, help="presets: timed runs per point (median wall time)")
    ap.add_argument("--out", default="out/accuracy", help="directory for the CSV, PNGs, markdown and references")
    ap.add_argument("--plot-from", default=None, metavar="CSV",
                    help="run nothing: redraw the figures from an accuracy.csv into --out (e.g. --plot-from "
                         "docs/accuracy.csv --out docs/figures)")


def speed_arguments(ap) -> None:
    ap.add_argument("--repeat", type=int, default=3, help="repeats of each throughput case (median reported)")
    ap.add_argument("--warmup", type=float, default=3.0, help="simulated seconds before timing (start-up transient)")
    ap.add_argument("--measure", type=float, default=5.0, help="simulated seconds timed")
    ap.add_argument("--no-scaling", action="store_true", help="skip the cost-vs-DOF study")
    ap.add_argument("--no-pyelastica", action="store_true", help="skip the PyElastica comparison")
    ap.add_argument("--no-presets", action="store_true", help="skip the real-time factor of each accuracy preset")
    ap.add_argument("--no-steady", action="store_true",
                    help="skip the direct steady solver against time-stepping to the same steady state")
    ap.add_argument("--quick", action="store_true", help="fewer cases and repeats")
    ap.add_argument("--against", default=None, metavar="DIR",
                    help="only compare whole processes side by side: this checkout against the flagbot_sim in DIR "
                         "(e.g. a `git worktree` of an older commit, its kernel cache warmed first), in alternating "
                         "pairs, printing each command's ratio")
    ap.add_argument("--pairs", type=int, default=3, help="--against: pairs of runs per command (median reported)")


def startup_arguments(ap) -> None:
    ap.add_argument("--repeat", type=int, default=5, help="rounds of import, warm, cold runs (median and min - max "
                                                          "of each and of the ratios within a round)")
    ap.add_argument("--scene", default="design1", help="scene to run (default design1)")
    ap.add_argument("--no-cold", action="store_true", help="skip the cold runs (each compiles the scene's kernels)")
    ap.add_argument("--no-first-run", action="store_true",
                    help="skip the first and later runs at the scene's default duration (a cold one each round)")
    ap.add_argument("--breakdown", action="store_true", help="also time the phases of a warm start in one process")
    ap.add_argument("--kernels", action="store_true", help="also profile a cold compile of the scene's kernels: "
                                                           "every function numba compiles, by group, its seconds")


def flood_arguments(ap) -> None:
    ap.add_argument("--rates", default="0,5000,10000", help="comma-separated cmd_omega flood rates, msg/s (0 = no "
                                                            "flood; always measured)")
    ap.add_argument("--seconds", type=float, default=8.0, help="wall seconds measured per phase")
    ap.add_argument("--repeat", type=int, default=2, help="rounds of the interleaved phases")
    ap.add_argument("--scene", default="design1", help="scene sim_node runs (default design1)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="override a scene value (sim_node's scene_overrides), e.g. --set scene.preset=accurate")
    ap.add_argument("--publish-rate", type=float, default=50.0, help="sim_node's publish_rate (Hz)")
    ap.add_argument("--no-realtime", action="store_true", help="skip the real_time_factor 1 /clock check")
