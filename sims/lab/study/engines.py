"""Engines: where a study's cells run. Each calls ``on_result(cell, row)`` as cells finish, in the
order they finish; the caller writes the rows. Engines never write the store themselves.

- :class:`LocalEngine`: a pool of ``workers`` processes on this machine (``spawn`` start, one BLAS
  thread each), at most one cell per worker in flight; each worker dies with the study process,
  even a SIGKILLed one (:func:`sims.lab.study.worker.init_worker`). When a worker dies (killed, out of memory,
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
import re
import socket
import sys
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterator, Sequence

from decentral.errors import InputError
from sims.lab.study.cells import Cell
from sims.lab.study.worker import PINNED_ENV, init_worker, work

__all__ = ["ENGINES", "LocalEngine", "RayEngine", "make_engine", "OnResult", "one_line", "check_reachable"]

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


@contextlib.contextmanager
def _held_stderr(patience: float = 90.0, what: str = "Ray") -> Iterator[None]:
    """Hold what this process writes to file descriptor 2 (C++ included) while the block runs.

    While Ray connects, its C++ core logs a warning a second per failed try: when the block fails,
    what was held is dropped (the caller turns the failure into one line); when it succeeds, it is
    written to stderr then, so nothing is hidden. A block still running after ``patience`` seconds
    gives stderr back, with what was held, after one line saying it is still waiting.
    """
    import tempfile
    import threading

    sys.stderr.flush()
    with tempfile.TemporaryFile() as hold:
        saved = os.dup(2)
        os.dup2(hold.fileno(), 2)
        lock, state = threading.Lock(), {"held": True}

        def give_back(note: str = "") -> None:
            with lock:
                if not state["held"]:
                    return
                state["held"] = False
                sys.stderr.flush()
                os.dup2(saved, 2)
                if note:
                    os.write(2, note.encode())
                hold.seek(0)
                text = hold.read()
                if text and note:
                    os.write(2, text)

        timer = threading.Timer(patience, give_back, kwargs={"note": f"still waiting for {what} after "
                                                                  f"{patience:g} s; its messages follow\n"})
        timer.daemon = True
        timer.start()
        failed = True
        try:
            yield
            failed = False
        finally:
            timer.cancel()
            with lock:
                was_held = state["held"]
            if was_held:
                sys.stderr.flush()
                with lock:
                    state["held"] = False
                    os.dup2(saved, 2)
                if not failed:
                    hold.seek(0)
                    text = hold.read()
                    if text:
                        sys.stderr.write(text.decode(errors="replace"))
                        sys.stderr.flush()
            os.close(saved)


def _task_args(cell: Cell) -> tuple:
    """What a worker's task is called with: the input files' texts only when the cell has some."""
    base = (cell.command, dict(cell.params), cell.key)
    return (*base, dict(cell.texts)) if cell.texts else base


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
        :func:`sims.lab.study.worker.work`); must be importable by name in a fresh process.
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
                            row = pool.submit(self.task, *_task_args(cell)).result()
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
                    future = pool.submit(self.task, *_task_args(cell))
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
        A running cluster (``HOST:6379``, ``auto``, or ``ray://HOST:10001`` through Ray Client);
        ``None`` starts a local instance with ``workers`` CPUs and stops it afterwards.
    workers : int, optional
        CPUs of the local instance (default: all of this machine's).

    Notes
    -----
    Workers get :data:`PINNED_ENV` from the environment the local instance starts with (they
    inherit it), or on a cluster from the job's runtime environment; only on an instance the caller
    started is it set per task, which costs a fresh worker process per study. A cell's input files
    travel as one object in Ray's object store per distinct set of files, so no node needs them.
    A task that fails (a node without the package, a worker that dies) gets a ``failed`` row whose
    error is one line with the root cause, and the node's address when Ray reports it.
    """

    name = "ray"
    #: set PINNED_ENV on every task (a fresh worker per study) instead of on the job; None: only on a caller's instance
    per_task_env: bool | None = None

    def __init__(self, address: str | None = None, workers: int | None = None):
        try:
            import ray  # noqa: F401
        except ImportError:
            raise InputError("Ray is not installed: pip install 'decentral[ray]'", field="--engine") from None
        self.address, self.workers = address, workers
        self._own = False

    @contextlib.contextmanager
    def _session(self):
        import ray

        if ray.is_initialized():  # the caller's instance (e.g. a test module's): leave it running
            self._own = False
            yield ray
            return
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "logging_level": "ERROR"}
        if self.address:
            check_reachable(self.address)
            kwargs["address"] = self.address
        elif self.workers:
            kwargs["num_cpus"] = self.workers
        if self.address and not self.per_task_env:  # a cluster's workers: the job's environment
            kwargs["runtime_env"] = {"env_vars": dict(PINNED_ENV)}
        try:
            with _pinned_environment(), _held_stderr(what=f"Ray{' at ' + self.address if self.address else ''}"):
                ray.init(**kwargs)
        except Exception as err:  # ConnectionError, RuntimeError, a gRPC error through Ray Client, ...
            where = f" at {self.address}" if self.address else ""
            cause = one_line(err)
            if "AuthenticationError" in cause or "InvalidAuthToken" in cause:
                raise InputError(f"the Ray cluster{where} requires its token: set RAY_AUTH_MODE=token and give the "
                                 "token (`ray get-auth-token` on the head) in RAY_AUTH_TOKEN or ~/.ray/auth_token",
                                 field="--address") from None
            raise InputError(f"cannot start or reach Ray{where}: {cause}", field="--address") from None
        self._own = True
        try:
            yield ray
        finally:
            ray.shutdown()

    def run(self, cells: Sequence[Cell], on_result: OnResult) -> None:
        """Run every cell of ``cells``; ``on_result`` gets each row as its cell ends."""
        with self._session() as ray:
            options: dict[str, Any] = {"num_cpus": 1, "max_retries": 2}
            if self.per_task_env or (self.per_task_env is None and not self._own):
                options["runtime_env"] = {"env_vars": dict(PINNED_ENV)}
            task = ray.remote(work).options(**options)
            shipped: dict[tuple, Any] = {}  # one object per distinct set of input files
            pending = {}
            for c in cells:
                if c.texts:
                    ident = tuple(sorted((k, hash(v)) for k, v in c.texts.items()))
                    if ident not in shipped:
                        shipped[ident] = ray.put(dict(c.texts))
                    pending[task.remote(c.command, dict(c.params), c.key, shipped[ident])] = c
                else:
                    pending[task.remote(c.command, dict(c.params), c.key)] = c
            try:
                while pending:
                    done, _ = ray.wait(list(pending), num_returns=1)
                    for ref in done:
                        cell = pending.pop(ref)
                        try:
                            row = ray.get(ref)
                        except ray.exceptions.RayError as err:  # the task itself failed; a cell's own errors are rows
                            row = {**_died(cell, "Ray task failed: " + one_line(err)), **_where(err)}
                        on_result(cell, row)
            except BaseException:
                for ref in pending:
                    ray.cancel(ref, force=True)
                raise


_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
_EXCEPTION_LINE = re.compile(r"^([A-Za-z_][\w.]*(?:Error|Exception|Exit|Interrupt)(?:\([\w.]+\))?): (.+)$")


def one_line(err: BaseException) -> str:
    """One line saying what went wrong, with the root cause: ``ModuleNotFoundError: No module named 'sims'``.

    Ray's errors carry the remote traceback, coloured, in their text; the deepest
    ``SomeError: message`` line in it is the cause. The type of a wrapping error with no such
    line, and any ANSI colour, is dropped.
    """
    seen, chain = set(), []
    while err is not None and id(err) not in seen:  # the cause chain, outermost first
        seen.add(id(err))
        chain.append(err)
        err = getattr(err, "cause", None) or err.__cause__
    for e in reversed(chain):
        text = _ANSI.sub("", str(e))
        found = [m for m in map(_EXCEPTION_LINE.match, (line.strip() for line in text.splitlines())) if m]
        if found:
            kind, message = found[-1].groups()
            return f"{kind.split('(')[0].rsplit('.', 1)[-1]}: {message.strip()}"
    e = chain[-1]
    lines = [line.strip() for line in _ANSI.sub("", str(e)).splitlines() if line.strip()]
    return f"{type(e).__name__}: {lines[-1] if lines else 'no message'}"


_WORKER = re.compile(r"\(pid=(\d+), ip=([^\s,)]+)")


def _where(err: BaseException) -> dict[str, Any]:
    """The address and pid of the worker a Ray error came from, when it says (attributes or its header)."""
    out: dict[str, Any] = {}
    found = _WORKER.search(_ANSI.sub("", str(err)))
    ip, pid = getattr(err, "ip", None), getattr(err, "pid", None)
    if found:
        pid, ip = pid or int(found.group(1)), ip or found.group(2)
    if ip:
        out["address"] = ip
    if pid:
        out["pid"] = int(pid)
    return out


#: the client preface of HTTP/2 (RFC 9113 §3.4) and an empty SETTINGS frame: a gRPC server answers with SETTINGS
_H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """Refuse a cluster address where no Ray answers, before Ray tries (and retries for minutes).

    ``HOST:PORT`` and ``ray://HOST:PORT`` are checked with one TCP connection that opens an HTTP/2
    conversation, as Ray's gRPC services speak: nothing listening, or a listener that does not
    answer as a gRPC server within ``timeout``, is refused. ``auto`` and other forms are left to
    Ray. Raises :class:`InputError` naming ``--address`` and what to do.
    """
    client = address.startswith("ray://")
    target = address[len("ray://"):] if client else address
    host, sep, port = target.rpartition(":")
    if not sep or not port.isdigit() or not host:
        if client:
            raise InputError(f"expected ray://HOST:PORT, got {address!r}", field="--address")
        return  # "auto", or a form Ray resolves itself
    what = ("Ray Client server (ray start --head starts one on port 10001)" if client
            else "Ray cluster (start one with `ray start --head`, or give HEAD:6379 of a running one)")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout) as conn:
            conn.sendall(_H2_PREFACE)
            reply = conn.recv(9)
    except socket.timeout:
        reply = b""
    except OSError as err:
        reason = err.strerror or type(err).__name__
        raise InputError(f"cannot reach the {what} at {target}: {reason}", field="--address") from None
    if len(reply) < 4 or reply[3] != 0x04:  # the 4th byte of a frame header is its type; SETTINGS = 4
        raise InputError(f"{target} does not answer as a {what.split(' (')[0]} (no gRPC reply within {timeout:g} s): "
                         "is it the right host and port?", field="--address")


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
