"""The sweep engines (serial, local process pool, Dask) kept open over many small batches.

A fit or a design search evaluates its model in dozens of batches of a few tasks each (the residuals at one
parameter vector, then the p finite-difference columns of the Jacobian). :func:`flagbot_sim.sweep.engines.run_tasks`
starts a pool per call, which costs seconds per batch (spawned interpreters import numpy, scipy and the compiled
kernels afresh); :class:`Engine` starts it once, with the sweep engines' own settings (spawn start, one BLAS thread
per worker, workers that leave Ctrl-C to the parent, a Dask LocalCluster bound to 127.0.0.1), and returns every
batch's results in task order. The task functions take and return plain picklable data and depend on nothing
but their task, so the numbers are the same on every engine and for any number of workers.
"""
from __future__ import annotations

from typing import Callable

from ..sweep.engines import ENGINES, default_workers, worker_init
from ..workers import single_thread_env
from ..sweep.grid import SweepError


class Engine:
    """``map(fn, tasks)`` on one of the sweep engines; a context manager (the pool or cluster is closed on exit)."""

    def __init__(self, engine: str = "local", workers: int | None = None, scheduler: str | None = None):
        if engine not in ENGINES:
            raise SweepError(f"--engine {engine!r}: choose one of {', '.join(ENGINES)}")
        if scheduler and engine != "dask":
            raise SweepError("--scheduler is only used with --engine dask")
        if workers is not None and workers < 1:
            raise SweepError(f"--workers must be at least 1, got {workers}")
        if engine == "dask":
            from ..optional import require
            require("dask", "--engine dask")    # before any work; MissingExtra: reported by the command's entry
        self.engine, self.scheduler = engine, scheduler
        self.workers = 1 if engine == "serial" else (workers or default_workers())
        self._pool = None
        self._client = None
        self._cluster = None
        self.tasks_run = 0

    @property
    def where(self) -> str:
        if self.engine == "serial":
            return "serial, this process"
        if self.engine == "dask" and self.scheduler:
            return f"dask, {self.scheduler}"
        return f"{self.engine}, {self.workers} worker(s)"

    def __enter__(self) -> "Engine":
        return self

    def __exit__(self, *exc) -> None:
        self.close(cancel=exc[0] is not None)

    def map(self, fn: Callable[[dict], dict], tasks: list[dict]) -> list[dict]:
        """fn(task) for every task, in task order."""
        self.tasks_run += len(tasks)
        if not tasks:
            return []
        if self.engine == "serial":
            return [fn(t) for t in tasks]
        if self.engine == "local":
            return self._map_local(fn, tasks)
        return self._map_dask(fn, tasks)

    def _map_local(self, fn, tasks):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures.process import BrokenProcessPool
        if self._pool is None:
            single_thread_env()
            self._pool = ProcessPoolExecutor(max_workers=self.workers,
                                             mp_context=multiprocessing.get_context("spawn"),
                                             initializer=worker_init)
        try:
            return list(self._pool.map(fn, tasks))
        except BrokenProcessPool as exc:
            self.close(cancel=True)
            raise SweepError(f"a worker process died ({exc})") from None

    def _map_dask(self, fn, tasks):
        if self._client is None:
            import logging

            from dask.distributed import Client, LocalCluster
            if self.scheduler:
                try:
                    self._client = Client(self.scheduler, timeout="20s")
                except (OSError, TimeoutError) as exc:
                    raise SweepError(f"--scheduler {self.scheduler}: cannot connect ({exc})") from None
            else:
                single_thread_env()
                self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                             host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                             worker_dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)
                self._client = Client(self._cluster)
        from distributed import KilledWorker
        futures = [self._client.submit(fn, t, pure=False) for t in tasks]
        try:
            return self._client.gather(futures)
        except KilledWorker as exc:
            raise SweepError(f"Dask gave up on a task after its workers died ({exc})") from None
        finally:
            self._client.cancel(futures)

    def close(self, cancel: bool = False) -> None:
        if self._pool is not None:
            pool, self._pool = self._pool, None
            if not cancel:
                pool.shutdown(wait=True)
            else:
                # interrupted: drop queued tasks and stop the workers now (they ignore SIGINT and SIGTERM)
                procs = list((getattr(pool, "_processes", None) or {}).values())
                pool.shutdown(wait=False, cancel_futures=True)
                for p in procs:
                    if p.is_alive():
                        p.kill()
                for p in procs:
                    p.join(timeout=5)
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None
