"""Engines: where a study's cells run. Each calls ``on_result(cell, row)`` as cells finish, in the
order they finish; the caller writes the rows. Engines never write the store themselves.

- :class:`LocalEngine`: a pool of ``workers`` processes on this machine (``spawn`` start, one BLAS
  thread each), at most one cell per worker in flight; each worker dies with the study process,
  even a SIGKILLed one (:func:`sims.study.worker.init_worker`). When a worker dies (killed, out of memory,
  crashed) the pool breaks for every cell in flight: each of those is run again alone, and the one
  that kills its worker again gets a 'failed' row; the rest go on in a fresh pool.
- :class:`RayEngine`: the same cells as Ray tasks (one CPU each), on a local Ray instance or the
  cluster at ``address`` (``ray start --head`` on one machine, ``ray start --address=HEAD:6379``
  on the others). Ray is an optional extra: ``pip install 'decentral[ray]'``.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterator, Sequence

from decentral.errors import InputError
from sims.study.cells import Cell
from sims.study.worker import PINNED_ENV, init_worker, work

__all__ = ["ENGINES", "LocalEngine", "RayEngine", "make_engine", "OnResult"]

OnResult = Callable[[Cell, dict], None]


@contextlib.contextmanager
def _pinned_environment() -> Iterator[None]:
    """:data:`PINNED_ENV` in ``os.environ`` while worker processes are started (restored after)."""
    saved = {k: os.environ.get(k) for k in PINNED_ENV}
    os.environ.update(PINNED_ENV)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _died(cell: Cell, why: str) -> dict[str, Any]:
    return {"key": cell.key, "status": "failed", "error": why, "seconds": None, "peak_mb": None, "metrics": {}}


class LocalEngine:
    """Run cells in ``workers`` processes on this machine.

    Parameters
    ----------
    workers : int
        Worker processes (>= 1).
    task : callable
        What a worker runs for a cell: ``task(command, params, key) -> row`` (default
        :func:`sims.study.worker.work`); must be importable by name in a fresh process.
    """

    name = "local"

    def __init__(self, workers: int = 1, task: Callable[..., dict] = work):
        if workers < 1:
            raise InputError(f"must be >= 1, got {workers}", field="--workers")
        self.workers, self.task = int(workers), task

    def run(self, cells: Sequence[Cell], on_result: OnResult) -> None:
        """Run every cell of ``cells``; ``on_result`` gets each row as its cell ends."""
        queue = list(reversed(cells))  # a stack: the next cell is at the end
        with _pinned_environment():
            while queue:
                with self._pool_of(self.workers) as pool:
                    queue, suspects = self._drain(pool, queue, on_result)
                for cell in suspects:  # in flight when a worker died: find out which one it was
                    with self._pool_of(1) as pool:
                        try:
                            row = pool.submit(self.task, cell.command, dict(cell.params), cell.key).result()
                        except BrokenProcessPool:
                            row = _died(cell, "worker process died while running this cell "
                                              "(killed, out of memory or crashed)")
                    on_result(cell, row)

    @contextlib.contextmanager
    def _pool_of(self, workers: int) -> Iterator[ProcessPoolExecutor]:
        pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=init_worker, initargs=(os.getpid(),))
        try:
            yield pool
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown(wait=True)

    def _drain(self, pool: ProcessPoolExecutor, queue: list[Cell], on_result: OnResult):
        """Feed ``pool`` one cell per worker until ``queue`` is empty or a worker dies.

        Returns the cells not started and those that were in flight when a worker died.
        """
        running: dict[Future, Cell] = {}
        while queue or running:
            while queue and len(running) < self.workers:
                cell = queue[-1]
                try:
                    future = pool.submit(self.task, cell.command, dict(cell.params), cell.key)
                except BrokenProcessPool:  # a worker died since the last wait: the cells in flight are suspects
                    return queue, list(running.values())
                running[future] = queue.pop()
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            suspects = []
            for future in done:
                cell = running.pop(future)
                try:
                    row = future.result()
                except BrokenProcessPool:
                    suspects.append(cell)
                    continue
                on_result(cell, row)
            if suspects:
                return queue, suspects + list(running.values())
        return queue, []


class RayEngine:
    """Run cells as Ray tasks (one CPU each) on a local instance or the cluster at ``address``.

    Parameters
    ----------
    address : str, optional
        A running cluster (``HOST:6379``, ``auto``, or ``ray://HOST:10001``); ``None`` starts a
        local instance with ``workers`` CPUs and stops it afterwards.
    workers : int, optional
        CPUs of the local instance (default: all of this machine's).
    """

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None):
        try:
            import ray  # noqa: F401
        except ImportError:
            raise InputError("Ray is not installed: pip install 'decentral[ray]'", field="--engine") from None
        self.address, self.workers = address, workers

    @contextlib.contextmanager
    def _session(self):
        import ray

        if ray.is_initialized():  # the caller's instance (e.g. a test module's): leave it running
            yield ray
            return
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "logging_level": "ERROR"}
        if self.address:
            kwargs["address"] = self.address
        elif self.workers:
            kwargs["num_cpus"] = self.workers
        try:
            with _pinned_environment():
                ray.init(**kwargs)
        except (ConnectionError, RuntimeError, ValueError) as err:
            raise InputError(f"cannot start or reach Ray: {err}", field="--address") from None
        try:
            yield ray
        finally:
            ray.shutdown()

    def run(self, cells: Sequence[Cell], on_result: OnResult) -> None:
        """Run every cell of ``cells``; ``on_result`` gets each row as its cell ends."""
        with self._session() as ray:
            task = ray.remote(work).options(num_cpus=1, max_retries=2, runtime_env={"env_vars": dict(PINNED_ENV)})
            pending = {task.remote(c.command, dict(c.params), c.key): c for c in cells}
            try:
                while pending:
                    done, _ = ray.wait(list(pending), num_returns=1)
                    for ref in done:
                        cell = pending.pop(ref)
                        try:
                            row = ray.get(ref)
                        except ray.exceptions.RayError as err:  # the worker died; the cell's own errors are rows
                            row = _died(cell, f"Ray task failed: {type(err).__name__}: {str(err).splitlines()[0]}")
                        on_result(cell, row)
            except BaseException:
                for ref in pending:
                    ray.cancel(ref, force=True)
                raise


ENGINES = ("local", "ray")


def make_engine(name: str, workers: int | None = None, address: str | None = None):
    """The engine called ``name`` (``local`` or ``ray``)."""
    if name == "local":
        if address:
            raise InputError("only applies with --engine ray", field="--address")
        return LocalEngine(workers or 1)
    if name == "ray":
        return RayEngine(address, workers)
    raise InputError(f"must be one of {', '.join(ENGINES)}, got {name!r}", field="--engine")
