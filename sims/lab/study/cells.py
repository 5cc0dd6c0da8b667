"""Cells: what one point of a study's grid runs, and the checks made before any of them runs.

A cell is fully determined by its command and parameters (seed included): it calls the library in
the process it is given, never the CLI, and returns one flat row. :func:`execute` is what every
engine runs; it never raises for a failing cell (the row says ``status = 'failed'`` and why), and
measures the cell's wall time and peak memory.
"""

from __future__ import annotations

import importlib
import os
import socket
import sys
import time
import traceback
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping

from decentral.errors import InputError
from sims.lab.study.spec import StudySpec, cell_key

__all__ = ["CELL_COMMANDS", "Cell", "ROW_STATUS", "metrics_of", "check_cells", "execute", "run_cell", "placement"]

#: key a cell's metrics may carry to set its row's ``run_status``: the decentralized run's ``stats.status``
#: ('ok', or 'degraded' when it finished but some step did not converge; :mod:`sims.runners.run_status`)
ROW_STATUS = "_status"

#: study command -> module with ``OPTIONS``, ``METRICS``, ``normalize(params)`` and ``run(params)``
CELL_COMMANDS: dict[str, str] = {
    "localize": "sims.lab.study.localize_cell",
    "ensemble": "sims.lab.study.ensemble_cell",
}


def _module(command: str):
    if command not in CELL_COMMANDS:
        raise InputError(f"must be one of {', '.join(CELL_COMMANDS)}, got {command!r}", field="command")
    return importlib.import_module(CELL_COMMANDS[command])


def metrics_of(command: str) -> tuple[str, ...]:
    """The metric columns of ``command``, in table order."""
    return tuple(_module(command).METRICS)


@dataclass(frozen=True)
class Cell:
    """One point of the grid.

    Attributes
    ----------
    command : str
    params : Mapping[str, Value]
        Normalized parameters ([fixed] and [grid] values).
    key : str
        :func:`sims.lab.study.spec.cell_key` of ``params`` (and of the input files' hashes): the cell's
        identity in the store.
    texts : Mapping[str, str]
        Contents of the cell's input files by key (``log``, ``truth``), read on the driver; empty
        for a simulated cell.
    """

    command: str
    params: Mapping[str, Any]
    key: str
    texts: Mapping[str, str] = field(default_factory=dict)


def check_cells(spec: StudySpec) -> list[Cell]:
    """Every cell of ``spec``, checked and normalized; raises :class:`InputError` before any runs.

    The error names the spec file and the key (``[fixed] n_asemblies``). Input files a cell names
    (a recorded ``log``) are read and validated here, once each; an error in one names that file
    and its field.
    """
    module = _module(spec.command)
    base = Path(spec.source).parent if spec.source and not spec.source.startswith("<") else Path.cwd()
    cells, seen, cache = [], set(), {}
    for params in spec.cells():
        try:
            normalized = module.normalize(params)
        except InputError as err:
            where = f"{spec.section_of(err.field)} {err.field}" if err.field in params else err.field
            raise InputError(err.message, source=spec.source, field=where) from None
        texts = module.inputs(normalized, base, cache) if hasattr(module, "inputs") else {}
        key = cell_key({**normalized, **module.digest(texts)} if texts else normalized)
        if key in seen:  # e.g. loss = [0, 0.0]: one cell written twice
            raise InputError(f"two grid values name the same cell {key}", source=spec.source, field="[grid]")
        seen.add(key)
        cells.append(Cell(spec.command, normalized, key, texts))
    return cells


def _reset_peak_memory() -> bool:
    """Reset this process's resident-memory high-water mark (Linux); False where unsupported."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _peak_memory_mb() -> float | None:
    """Peak resident memory of this process since the last reset [MB] (``VmHWM``), or ``None``."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # lifetime peak: an upper bound


def run_cell(command: str, params: Mapping[str, Any], texts: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The metrics of one cell, computed in this process (raises on failure)."""
    return _module(command).run(params, texts) if texts else _module(command).run(params)


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def execute(command: str, params: Mapping[str, Any], key: str, texts: Mapping[str, str] | None = None
            ) -> dict[str, Any]:
    """Run one cell and return its row (never raises for the cell's own failures).

    Returns
    -------
    dict
        ``key``, ``status`` ('ok' or 'failed'), ``run_status`` (a decentralized run's ``stats.status``:
        'ok', or 'degraded' when some step did not converge, its metrics still recorded; ``None`` where
        the command has none; :mod:`sims.runners.run_status`), ``error`` (one line, or ``None``), ``seconds`` (wall
        time of the cell), ``cpu_seconds`` (its CPU time in the worker), ``peak_mb`` (peak resident
        memory of the process during the cell), ``host``, ``pid``, ``node`` and ``address`` (see
        :func:`placement`), ``started``, ``finished`` and ``metrics`` (a dict; empty when failed).
    """
    _module(command)  # imported before the clock starts: a cell's time is its own work
    _reset_peak_memory()
    started = _now()
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        metrics, status, error = run_cell(command, params, texts), "ok", None
        run_status = metrics.pop(ROW_STATUS, None)
    except Exception as err:  # a failing cell is a result, not the end of the study
        frame = traceback.extract_tb(err.__traceback__)[-1] if err.__traceback__ else None
        where = f" (at {os.path.basename(frame.filename)}:{frame.lineno})" if frame else ""
        metrics, status, error, run_status = {}, "failed", f"{type(err).__name__}: {err}{where}", None
    return {
        "key": key, "status": status, "run_status": run_status, "error": error, "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - c0, "peak_mb": _peak_memory_mb(), "host": socket.gethostname(),
        "pid": os.getpid(), **placement(), "started": started, "finished": _now(), "metrics": metrics,
    }


def placement() -> dict[str, str | None]:
    """Where this process runs: ``node`` and ``address``.

    In a Ray worker: the Ray node id (unique per raylet, even when two share a machine and its
    hostname) and the node's IP address. Elsewhere (the local pool): the hostname and ``None``
    (the row's ``host`` and ``pid`` then say which process it was).
    """
    ray = sys.modules.get("ray")  # never imported here: a Ray worker has it already
    if ray is not None and ray.is_initialized():
        try:
            node = ray.get_runtime_context().get_node_id()
        except Exception:  # an older or partial Ray: the hostname still says something
            return {"node": socket.gethostname(), "address": None}
        worker = getattr(getattr(ray, "_private", None), "worker", None)
        # the address the node was started with (--node-ip-address), which the cluster knows it by
        address = getattr(getattr(worker, "global_worker", None), "node_ip_address", None)
        return {"node": node, "address": address or ray.util.get_node_ip_address()}
    return {"node": socket.gethostname(), "address": None}
