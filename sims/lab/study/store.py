"""The study store: one SQLite file, ``DIR/study.sqlite``, written only by the process that runs the study.

Tables
------
``runs``
    One row per finished cell, inserted and committed in one transaction when the cell ends:
    ``id``, ``cell_key`` (the canonical JSON of the cell's parameters, UNIQUE: a cell can never
    have two rows), ``cell_hash``, one column per ``[fixed]`` and ``[grid]`` key, ``status``
    ('ok' or 'failed'), ``error``, ``seconds`` (wall time of the cell), ``cpu_seconds`` (its CPU
    time in the worker), ``peak_mb`` (peak resident
    memory of the worker during the cell), one column per metric of the command (NULL where it
    does not apply), then ``engine``, ``host``, ``pid``, ``started``, ``finished`` (UTC, ISO 8601)
    and ``invocation`` (the ``invocations.id`` that ran it), ``node`` (the Ray node id, or the
    hostname on the local pool) and ``address`` (the Ray node's IP address; NULL on the local pool),
    ``run_status`` (a decentralized run's ``stats.status``: 'ok' or 'degraded'; NULL where the cell's
    command has none).
``study``
    Key/value facts of the study: ``name``, ``command``, ``params`` (JSON list of the parameter
    columns), ``metrics`` (JSON list), ``schema`` (this layout's version), ``spec`` (the text of
    the spec that created the store).
``invocations``
    Provenance, one row per run of ``decentral study`` on this store: start and end, engine,
    workers, address, the spec's text and hash, the git revision of the code when known, Python,
    platform, host, package versions (JSON), the cells run and failed, the driver's ``pid`` and the
    ``status``: ``running``, ``finished``, ``interrupted`` (stopped by a signal or an error) or
    ``killed`` (its process vanished without closing the row; set by the next run on the store).

The database is in WAL mode with ``synchronous = FULL``: a process killed at any instant leaves
every committed row and no partial one, so a resumed study runs exactly the cells without a row.
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
from contextlib import closing
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from decentral.errors import InputError

__all__ = ["SCHEMA", "DB_NAME", "BOOKKEEPING", "StudyStore", "open_store", "read_runs"]

SCHEMA = "decentral.study/1"
DB_NAME = "study.sqlite"
#: columns of ``runs`` that are neither parameters nor metrics
BOOKKEEPING = ("id", "cell_key", "cell_hash", "status", "error", "seconds", "cpu_seconds", "peak_mb",
               "engine", "host", "pid", "started", "finished", "invocation", "node", "address", "run_status")
#: columns added after the first stores were written: (table, column, SQL type), added on open where missing
ADDED_COLUMNS = (("runs", "node", "TEXT"), ("runs", "address", "TEXT"), ("invocations", "pid", "INTEGER"),
                 ("runs", "run_status", "TEXT"))


def _q(name: str) -> str:
    """A quoted SQL identifier (keys are checked to be plain names; quoting keeps SQL words usable)."""
    return '"' + name.replace('"', '""') + '"'


def _connect(path: Path) -> sqlite3.Connection:
    con = sqlite3.connect(str(path), timeout=30.0, isolation_level=None)  # explicit transactions
    con.execute("PRAGMA journal_mode=WAL")
    con.execute("PRAGMA synchronous=FULL")
    return con


class StudyStore:
    """An open store for one study (create with :func:`open_store`).

    Parameters
    ----------
    path : Path
        The database file.
    params, metrics : sequence of str
        Parameter and metric columns of ``runs``.
    """

    def __init__(self, con: sqlite3.Connection, path: Path, params: Sequence[str], metrics: Sequence[str]):
        self.con, self.path = con, path
        self.params, self.metrics = tuple(params), tuple(metrics)

    # --- reading ------------------------------------------------------------------------------
    def done_keys(self) -> set[str]:
        """The ``cell_key`` of every cell that has a row."""
        return {row[0] for row in self.con.execute("SELECT cell_key FROM runs")}

    def count(self, status: str | None = None) -> int:
        """Rows in ``runs`` (with ``status`` when given)."""
        if status is None:
            return self.con.execute("SELECT COUNT(*) FROM runs").fetchone()[0]
        return self.con.execute("SELECT COUNT(*) FROM runs WHERE status = ?", (status,)).fetchone()[0]

    # --- writing ------------------------------------------------------------------------------
    def add_run(self, params: Mapping[str, Any], result: Mapping[str, Any], engine: str, invocation: int) -> bool:
        """Insert the row of one finished cell in one transaction; False if the cell already had one."""
        metrics = result.get("metrics") or {}
        values = {
            "cell_key": result["key"], "cell_hash": hashlib.sha256(result["key"].encode()).hexdigest()[:16],
            **{k: params.get(k) for k in self.params},
            "status": result["status"], "error": result["error"], "seconds": result["seconds"],
            "cpu_seconds": result.get("cpu_seconds"), "peak_mb": result.get("peak_mb"),
            **{m: _sql_value(metrics.get(m)) for m in self.metrics},
            "engine": engine, "host": result.get("host"), "pid": result.get("pid"),
            "started": result.get("started"), "finished": result.get("finished"), "invocation": invocation,
            "node": result.get("node"), "address": result.get("address"), "run_status": result.get("run_status"),
        }
        cols = ", ".join(_q(c) for c in values)
        marks = ", ".join("?" for _ in values)
        with self._transaction():
            cur = self.con.execute(f"INSERT OR IGNORE INTO runs ({cols}) VALUES ({marks})", tuple(values.values()))
        return cur.rowcount == 1

    def delete_failed(self) -> int:
        """Remove every 'failed' row (so that those cells run again); returns how many."""
        with self._transaction():
            return self.con.execute("DELETE FROM runs WHERE status = 'failed'").rowcount

    def begin_invocation(self, info: Mapping[str, Any]) -> int:
        """Record the provenance of this run; returns its invocation id."""
        cols = ", ".join(_q(c) for c in info)
        with self._transaction():
            cur = self.con.execute(f"INSERT INTO invocations ({cols}) VALUES ({', '.join('?' for _ in info)})",
                                   tuple(info.values()))
        return int(cur.lastrowid)

    def close_vanished_invocations(self, host: str, alive: "Callable[[int], bool]") -> list[int]:
        """Mark ``killed`` every invocation left ``running`` whose driver is gone; returns their ids.

        A driver killed outright (SIGKILL, power loss) never closes its row. One on ``host`` whose
        ``pid`` is no longer ``alive`` is closed, with the time of its last row and the counts of
        the rows it wrote; a row of another host, or one without a pid, is left alone (that
        driver may still be running).
        """
        with self._transaction():
            stale = [i for i, h, pid in self.con.execute(
                "SELECT id, host, pid FROM invocations WHERE status = 'running'") if h == host and pid and not alive(pid)]
            for i in stale:
                last, ran, failed = self.con.execute(
                    "SELECT MAX(finished), COUNT(*), SUM(status = 'failed') FROM runs WHERE invocation = ?", (i,)).fetchone()
                self.con.execute("UPDATE invocations SET status = 'killed', finished = ?, cells_run = ?, "
                                 "cells_failed = ? WHERE id = ?", (last, ran, failed or 0, i))
        return stale

    def end_invocation(self, invocation: int, **info: Any) -> None:
        """Complete a invocation's row (end time, counts)."""
        sets = ", ".join(f"{_q(k)} = ?" for k in info)
        with self._transaction():
            self.con.execute(f"UPDATE invocations SET {sets} WHERE id = ?", (*info.values(), invocation))

    def close(self) -> None:
        self.con.close()

    def _transaction(self):
        return _Transaction(self.con)


class _Transaction:
    def __init__(self, con: sqlite3.Connection):
        self.con = con

    def __enter__(self):
        self.con.execute("BEGIN IMMEDIATE")
        return self.con

    def __exit__(self, kind, value, tb):
        self.con.execute("COMMIT" if kind is None else "ROLLBACK")
        return False


def _sql_value(value: Any) -> Any:
    """Numbers, strings and NULL go in as they are; numpy scalars become Python numbers."""
    if value is None or isinstance(value, (str, int, float)):
        return value
    if hasattr(value, "item"):
        return value.item()
    return json.dumps(value)


def _create(con: sqlite3.Connection, name: str, command: str, params: Sequence[str], metrics: Sequence[str],
            spec_text: str) -> None:
    param_cols = "".join(f"{_q(p)}, " for p in params)
    metric_cols = "".join(f"{_q(m)} REAL, " for m in metrics)
    with _Transaction(con):
        con.execute("CREATE TABLE study (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
        con.executemany("INSERT INTO study VALUES (?, ?)", [
            ("schema", SCHEMA), ("name", name), ("command", command), ("params", json.dumps(list(params))),
            ("metrics", json.dumps(list(metrics))), ("spec", spec_text)])
        con.execute(
            "CREATE TABLE runs (id INTEGER PRIMARY KEY, cell_key TEXT NOT NULL UNIQUE, cell_hash TEXT NOT NULL, "
            f"{param_cols}status TEXT NOT NULL CHECK (status IN ('ok', 'failed')), error TEXT, seconds REAL, "
            f"cpu_seconds REAL, peak_mb REAL, {metric_cols}engine TEXT, host TEXT, pid INTEGER, started TEXT, "
            "finished TEXT, invocation INTEGER, node TEXT, address TEXT, run_status TEXT)")
        con.execute(
            "CREATE TABLE invocations (id INTEGER PRIMARY KEY, started TEXT, finished TEXT, engine TEXT, "
            "workers INTEGER, address TEXT, spec TEXT, spec_sha256 TEXT, git_revision TEXT, python TEXT, "
            "platform TEXT, host TEXT, packages TEXT, cells_total INTEGER, cells_run INTEGER, "
            "cells_failed INTEGER, status TEXT, pid INTEGER)")


def _study_facts(con: sqlite3.Connection) -> dict[str, str]:
    return dict(con.execute("SELECT key, value FROM study").fetchall())


def open_store(directory: str | Path, name: str, command: str, params: Sequence[str], metrics: Sequence[str],
               spec_text: str = "") -> StudyStore:
    """Open ``directory/study.sqlite``, creating it (and the directory) for a new study.

    An existing store must hold the same command with the same parameter keys (its columns);
    otherwise :class:`InputError` says what differs. Changed values are new cells: their rows are
    added beside the old ones.
    """
    directory = Path(directory)
    path = directory / DB_NAME
    taken = sorted(set(params) & (set(metrics) | set(BOOKKEEPING)))
    if taken:
        raise InputError(f"{', '.join(taken)} name(s) a column of the results (a metric or bookkeeping column), "
                         "not a parameter", field=taken[0])
    try:
        directory.mkdir(parents=True, exist_ok=True)
        con = _connect(path)
    except (OSError, sqlite3.Error) as err:
        raise InputError(f"cannot open the study store: {err}", source=str(path)) from None
    try:
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if "study" not in tables:
            if tables:
                raise InputError("is not a study store (no 'study' table)", source=str(path))
            _create(con, name, command, params, metrics, spec_text)
        else:
            _check_same_study(_study_facts(con), path, command, params)
            _add_missing_columns(con)
    except sqlite3.DatabaseError as err:
        con.close()
        raise InputError(f"not a readable study store: {err}", source=str(path)) from None
    except InputError:
        con.close()
        raise
    return StudyStore(con, path, params, metrics)


def _add_missing_columns(con: sqlite3.Connection) -> None:
    """Add the :data:`ADDED_COLUMNS` a store written by an earlier version lacks (NULL in its old rows)."""
    for table, column, kind in ADDED_COLUMNS:
        have = {r[1] for r in con.execute(f"PRAGMA table_info({_q(table)})")}
        if have and column not in have:
            with _Transaction(con):
                con.execute(f"ALTER TABLE {_q(table)} ADD COLUMN {_q(column)} {kind}")


def _check_same_study(facts: Mapping[str, str], path: Path, command: str, params: Sequence[str]) -> None:
    if facts.get("schema") != SCHEMA:
        raise InputError(f"holds a study store of another version ({facts.get('schema')!r}, expected {SCHEMA!r})",
                         source=str(path), field="schema")
    if facts.get("command") != command:
        raise InputError(f"holds a study of command {facts.get('command')!r}, not {command!r}: "
                         "write this study to another directory", source=str(path), field="command")
    stored = json.loads(facts.get("params", "[]"))
    if set(stored) != set(params):
        added, dropped = sorted(set(params) - set(stored)), sorted(set(stored) - set(params))
        what = "; ".join(part for part in (f"new key(s) {', '.join(added)}" if added else "",
                                           f"key(s) no longer given {', '.join(dropped)}" if dropped else "") if part)
        raise InputError(f"holds a study with other parameter keys ({what}): each key is a column of its "
                         "rows, so write this study to another directory", source=str(path), field="[fixed]/[grid]")


def read_runs(path: str | Path) -> tuple[dict[str, str], list[dict[str, Any]], list[dict[str, Any]]]:
    """Read a store without changing it: ``(study facts, runs rows, invocations rows)``.

    Works on a bare ``runs`` table too (facts and invocations then come back empty).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such study store", source=str(path))
    try:
        with closing(sqlite3.connect(str(path))) as con:
            con.row_factory = sqlite3.Row
            tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
            if "runs" not in tables:
                raise InputError("has no 'runs' table", source=str(path))
            facts = _study_facts(con) if "study" in tables else {}
            runs = [dict(r) for r in con.execute("SELECT * FROM runs ORDER BY rowid")]
            invocations = ([dict(r) for r in con.execute("SELECT * FROM invocations ORDER BY id")]
                        if "invocations" in tables else [])
    except sqlite3.DatabaseError as err:
        raise InputError(f"not a readable study store: {err}", source=str(path)) from None
    return facts, runs, invocations
