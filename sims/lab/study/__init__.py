"""Studies: declared sweeps of localize or ensemble cells, stored in SQLite, run locally or on Ray.

- :mod:`sims.lab.study.spec`: the TOML spec (``name``, ``command``, ``[fixed]``, ``[grid]``) and cell keys;
- :mod:`sims.lab.study.cells`: what a cell runs (:mod:`~sims.lab.study.localize_cell`,
  :mod:`~sims.lab.study.ensemble_cell`), the checks made before any cell runs, :func:`execute`;
- :mod:`sims.lab.study.store`: the SQLite store (``runs``, ``study``, ``invocations``);
- :mod:`sims.lab.study.engines`: the local process pool and Ray;
- :mod:`sims.lab.study.runner`: :func:`run_study`, resumable;
- :mod:`sims.lab.study.report`: ``report.html`` and the figures, from the store alone.

Names are re-exported lazily: worker processes import :mod:`sims.lab.study.worker` without numpy, so
that their BLAS thread pools can be sized first.
"""

from __future__ import annotations

import importlib

__all__ = ["StudySpec", "read_spec", "parse_spec", "run_study", "StudyResult", "make_engine", "LocalEngine",
           "RayEngine", "write_report"]

_WHERE = {"StudySpec": "spec", "read_spec": "spec", "parse_spec": "spec", "run_study": "runner",
          "StudyResult": "runner", "make_engine": "engines", "LocalEngine": "engines", "RayEngine": "engines",
          "write_report": "report"}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"sims.lab.study.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'sims.lab.study' has no attribute {name!r}")
