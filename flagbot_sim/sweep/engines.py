"""Where the grid points run: ``serial`` (this process), ``local`` (a spawn-started process pool, one worker per
core) or ``dask`` (a Dask distributed cluster: ``--scheduler tcp://host:8786``, or a LocalCluster on this
machine bound to 127.0.0.1). All three call the same :func:`flagbot_sim.sweep.task.run_point` on the same
picklable task dicts and yield results as they finish; the caller streams them to the CSV.
"""
from __future__ import annotations

import os
import signal
from typing import Iterator

from .. import workers as worker_processes
from .grid import SweepError
from .task import run_point

ENGINES = ("local", "dask", "serial")



def default_workers() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:     # not Linux
        return os.cpu_count() or 1


def worker_count(engine: str, workers: int | None, n_tasks: int) -> int:
    """Worker processes that will run n_tasks: 1 for serial, else ``workers`` (default: the cores) but no more
    than there are tasks, and at least 1 (itself a valid ``workers``). With a remote Dask scheduler the cluster
    has its own workers and this is unused."""
    if workers is not None and workers < 1:
        raise SweepError(f"--workers must be at least 1, got {workers}")
    if engine == "serial":
        return 1
    return min(workers or default_workers(), max(1, n_tasks))


def worker_init() -> None:
    """A local pool worker's initializer (the sweep's and the fit's pools): the parent alone handles signals."""
    # Ctrl-C (and a scheduler's SIGTERM) goes to the whole process group: only the parent handles it (cancels,
    # then kills the workers); a worker stopped mid-task would only turn into a broken pool
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def start(engine: str, n_tasks: int) -> None:
    """Start what ``engine`` needs before its tasks exist, so that it loads while this process prepares them: the
    local engine's fork server (its imports and kernels, ~1.3 s on one core; :func:`flagbot_sim.workers.start`),
    which the pool's workers then fork from. Nothing for the other engines or without tasks."""
    if engine == "local" and n_tasks >= 1:
        worker_processes.start()


def run_serial(tasks: list[dict]) -> Iterator[dict]:
    for t in tasks:
        yield run_point(t)


def run_local(tasks: list[dict], workers: int) -> Iterator[dict]:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    worker_processes.single_thread_env()
    ex = ProcessPoolExecutor(max_workers=workers, mp_context=worker_processes.context(), initializer=worker_init)
    futures = [ex.submit(run_point, t) for t in tasks]
    finished = False
    try:
        for fut in as_completed(futures):
            yield fut.result()
        finished = True
    except BrokenProcessPool as exc:
        # a worker died without a Python exception (out of memory, a signal): the pool cannot go on
        raise SweepError(f"a worker process died ({exc}); finished points are saved, rerun to resume") from None
    finally:
        if finished:
            ex.shutdown(wait=True)
        else:
            # interrupted (Ctrl-C, or the consumer stopped): drop queued tasks and stop our own workers now
            # rather than waiting for their current point; finished points are already in the CSV
            procs = list((getattr(ex, "_processes", None) or {}).values())   # shutdown() forgets them
            ex.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                if p.is_alive():
                    p.kill()            # SIGKILL: the workers ignore SIGINT and SIGTERM
            for p in procs:
                p.join(timeout=5)


def run_dask(tasks: list[dict], workers: int, scheduler: str | None) -> Iterator[dict]:
    from ..optional import require
    require("dask", "flagbot sweep --engine dask")      # MissingExtra: reported by the command's entry point
    from dask.distributed import Client, LocalCluster, as_completed
    from distributed import KilledWorker
    import logging

    cluster = None
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise SweepError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
    else:
        worker_processes.single_thread_env()
        # every listener on the loopback interface: the scheduler, the workers, their nannies and the
        # dashboard (which only starts if bokeh is installed)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0",
                               silence_logs=logging.ERROR)
        client = Client(cluster)
    futures = []
    try:
        # pure=False: a fresh key per submission, so a long-lived scheduler never hands back a stale result
        futures = [client.submit(run_point, t, pure=False) for t in tasks]
        for fut in as_completed(futures):
            try:
                res = fut.result()
            except KilledWorker as exc:
                raise SweepError(f"Dask gave up on a task after its workers died ({exc}); finished points are "
                                 "saved, rerun to resume") from None
            yield res
    finally:
        if futures:
            client.cancel(futures)
        client.close()
        if cluster is not None:
            cluster.close()


def run_tasks(tasks: list[dict], engine: str, workers: int | None = None,
              scheduler: str | None = None) -> Iterator[dict]:
    """Run the tasks on the engine; ``workers`` as for :func:`worker_count` (passing its result changes nothing)."""
    if engine not in ENGINES:
        raise SweepError(f"--engine {engine!r}: choose one of {', '.join(ENGINES)}")
    if scheduler and engine != "dask":
        raise SweepError("--scheduler is only used with --engine dask")
    k = worker_count(engine, workers, len(tasks))
    if not tasks:
        return iter(())
    if engine == "serial":
        return run_serial(tasks)
    if engine == "local":
        return run_local(tasks, k)
    return run_dask(tasks, k, scheduler)
