"""``flagbot sweep SCENE --grid KEY=VALUES ... --out DIR`` and ``flagbot sweep-plot DIR``."""
from __future__ import annotations

import math
import signal
import sys
import time

from ..sweep.engines import ENGINES, default_workers, run_tasks, worker_count
from ..sweep.engines import start as start_engine
from ..sweep.grid import SweepError, parse_grid, validate
from ..sweep.store import SweepStore, manifest_identity
from ..sweep.task import FRAMEWORKS, SteadySettings, make_task

#: default cap on simulated time per DER run (s). Design 1 (eta_p L^4/EI ~ 28 s) is steady after ~12-20 s at
#: 20-250 rpm with the default 2 s window and rtol 1e-3; design 2 after ~6-10 s
DEFAULT_T_MAX = 60.0


class Terminated(KeyboardInterrupt):
    """SIGTERM (a batch scheduler's stop, ``kill PID``): handled like Ctrl-C, finished points kept."""


def _on_sigterm(signum, frame):
    raise Terminated


def register(subparsers) -> None:
    from ..cliutil import add_scene_arguments
    p = subparsers.add_parser(
        "sweep", help="parameter sweep: DER to steady state and the beam balance (LB, NLB w/o head, NLB) at every "
                      "grid point, one tidy CSV, resumable, plus the paper's figures",
        description="Every grid point is run by the DER simulator until v and omega_h stop changing (or --t-max) "
                    "and by the beam balance in each regime. Rows stream to DIR/results.csv as points finish; "
                    "rerunning the same command resumes, computing only the missing points.")
    add_scene_arguments(p)
    p.add_argument("--grid", action="append", default=[], metavar="KEY=VALUES", required=True,
                   help="a swept scene key and its values: comma list and/or inclusive start:stop:step ranges, "
                        "e.g. --grid n=2,3 --grid motor.omega_rpm=20:250:10 --grid flagellum.length=0.09,0.13. "
                        "Shorthands: n (robot.n_flagella), L (flagellum.length), rpm (motor.omega_rpm)")
    p.add_argument("--out", required=True, metavar="DIR", help="sweep directory (created; reused to resume)")
    p.add_argument("--engine", choices=ENGINES, default="local",
                   help="local: process pool, one worker per core (default); dask: a Dask distributed cluster; "
                        "serial: this process")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: a LocalCluster on 127.0.0.1)")
    p.add_argument("--workers", type=int, default=None, metavar="K",
                   help=f"worker processes for local / a Dask LocalCluster (default: cores, here {default_workers()})")
    p.add_argument("--method", choices=("steady", "time"), default="steady",
                   help="DER steady state of each point: 'steady' solves the relative equilibrium directly "
                        "(milliseconds; time-stepped where none is found), 'time' runs the simulator to the "
                        "steady-state rule (default: steady)")
    p.add_argument("--t-max", type=float, default=DEFAULT_T_MAX, metavar="S",
                   help=f"cap on simulated seconds per DER run (default {DEFAULT_T_MAX:g}); the CSV's hit_cap "
                        "says which points reached it")
    p.add_argument("--window", type=float, default=None, metavar="S",
                   help="steady-state window in simulated seconds (default: the scene's observe.steady_window)")
    p.add_argument("--rtol", type=float, default=None,
                   help="steady when omega_h and v change by less than this between consecutive windows, at three "
                        "checks half a window apart (default: the scene's observe.steady_rtol)")
    p.add_argument("--frameworks", default=",".join(FRAMEWORKS), metavar="LIST",
                   help=f"comma list from {', '.join(FRAMEWORKS)} (default: all)")
    p.add_argument("--no-plot", action="store_true", help="do not draw the figures at the end")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_sweep)

    q = subparsers.add_parser("sweep-plot", help="redraw a sweep's figures and summary from DIR/results.csv alone "
                                                 "(no simulation)")
    q.add_argument("dir", metavar="DIR")
    q.set_defaults(func=cmd_sweep_plot)


def _frameworks(text: str) -> tuple[str, ...]:
    items = tuple(x.strip() for x in text.split(",") if x.strip())
    bad = [x for x in items if x not in FRAMEWORKS]
    if bad or not items:
        raise SweepError(f"--frameworks: unknown {', '.join(map(repr, bad)) or 'empty list'}; choose from "
                         f"{', '.join(FRAMEWORKS)}")
    if len(set(items)) != len(items):
        raise SweepError("--frameworks lists a framework twice")
    return tuple(fw for fw in FRAMEWORKS if fw in items)     # canonical order: the manifest compares lists


def _check_beam_shape(base, grid: dict, frameworks: tuple[str, ...]) -> None:
    """Refuse beam frameworks on helical flagella: the beam balance is of naturally straight ones."""
    beams = [f for f in frameworks if f != "der"]
    pitches = grid.get("flagellum.helix_pitch", [base.flagellum.helix_pitch])
    helical = [p for p in pitches if p != 0.0]
    if beams and helical:
        raise SweepError(f"flagellum.helix_pitch = {helical[0]:g} m: the beam balance ({', '.join(beams)}) models "
                         "naturally straight flagella only; use --frameworks der for helical ones")


def _progress_text(res: dict) -> str:
    """The last finished point for the progress line ('--' where a value is missing, never 'nan')."""
    def num(x, spec, scale=1.0):
        try:
            x = scale * float(x)
        except (TypeError, ValueError):
            return "--"
        return format(x, spec) if math.isfinite(x) else "--"
    der = next((r for r in res["rows"] if r["framework"] == "der"), res["rows"][0])
    state = "ERROR" if der["error"] else ("CAP" if der["hit_cap"] else "steady")
    return (f"n={der['n']} L={num(der['L'], 'g', 1e3)}mm {num(der['omega_T_rpm'], 'g')}rpm {der['framework']}: "
            f"v={num(der['v'], '.4f', 1e3)}mm/s {state} {num(der['wall_seconds'], '.1f')}s")


def cmd_sweep(args) -> int:
    from ..progress import ProgressBar
    from ..scene import load_scene
    from ..scene_files import portable_source

    base = load_scene(args.scene, args.overrides)
    grid, points = validate(base, parse_grid(args.grid), base.overrides)     # base.overrides: the parsed --set
    if args.engine == "dask":           # refused before the sweep directory is made (MissingExtra, exit 2)
        from ..optional import require
        require("dask", "flagbot sweep --engine dask")
    settings = SteadySettings(t_max=args.t_max,
                              window=args.window if args.window is not None else base.observe.steady_window,
                              rtol=args.rtol if args.rtol is not None else base.observe.steady_rtol,
                              method=args.method)
    settings.check()
    frameworks = _frameworks(args.frameworks)
    _check_beam_shape(base, grid, frameworks)
    identity = manifest_identity(base.flat(), grid, settings.to_dict(), list(frameworks))
    store = SweepStore(args.out, grid, points, identity,
                       extra={"scene_name": base.scene.name, "scene_source": portable_source(base.source), "set": args.overrides,
                              "command": sys.argv[1:]}, scene_toml=base.to_toml())
    pending = store.pending()
    workers = worker_count(args.engine, args.workers, len(pending))     # what run_tasks will start
    start_engine(args.engine, len(pending))          # the local engine's fork server loads while we go on
    where = args.scheduler or ("this process" if args.engine == "serial" else f"{workers} worker(s)")
    print(f"sweep {base.scene.name}: {len(points)} points x {len(frameworks)} frameworks; "
          f"{len(points) - len(pending)} already in {store.csv_path}; computing {len(pending)} "
          f"[{args.engine}, {where}]", file=sys.stderr)
    tasks = [make_task(base, p.key, p.overrides(), settings, frameworks) for p in pending]
    preload = None if args.no_plot else _preload_plotting()
    bar = ProgressBar(len(pending), label="sweep", unit="pts", enabled=not args.quiet and bool(pending))
    t0 = time.perf_counter()
    done = 0
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        for res in run_tasks(tasks, args.engine, workers, args.scheduler):
            store.write_point(res)
            done += 1
            bar.update(done, _progress_text(res), force=done == len(pending))
    except KeyboardInterrupt as exc:
        bar.close()
        store.close()
        what = "terminated" if isinstance(exc, Terminated) else "interrupted"
        print(f"{what}: {done} of {len(pending)} points written to {store.csv_path}; rerun the same command "
              "to compute the rest", file=sys.stderr)
        return 128 + (signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT)
    finally:
        signal.signal(signal.SIGTERM, previous)
    bar.close()
    store.close()
    wall = time.perf_counter() - t0
    if pending:
        print(f"computed {done} points in {wall:.1f} s wall ({wall / done:.2f} s per point)", file=sys.stderr)
    if args.no_plot:
        return 0
    if preload is not None:
        preload.join()
    return _plot(args.out)


def _preload_plotting():
    """Import matplotlib and the figures' module in a thread while the points are computed (~0.6 s that the
    figures would otherwise wait for at the end; this process is idle while its workers compute)."""
    import threading

    def load():
        try:
            import matplotlib.backends.backend_agg  # noqa: F401
            import matplotlib.figure  # noqa: F401
            from ..sweep import plots  # noqa: F401
        except Exception:            # noqa: BLE001 -- _plot imports them again and reports the error there
            pass
    t = threading.Thread(target=load, name="flagbot-preload-plotting", daemon=True)
    t.start()
    return t


def _plot(directory) -> int:
    from ..sweep.plots import format_summary, make_all
    out = make_all(directory)
    print(format_summary(out["summary"]))
    print("figures: " + ", ".join(out["figures"]))
    errors = sum(len(g["errors"]) for g in out["summary"]["groups"])
    return 1 if errors else 0


def cmd_sweep_plot(args) -> int:
    return _plot(args.dir)
