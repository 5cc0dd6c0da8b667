"""The ``ensemble`` cell: make an ensemble, localize it, score it against its truth (Funiak et al. 2008).

The keys are those of ``decentral make-ensemble`` (``shape``, ``n``, ``seed``, ``radius``,
``lattice``, ``jitter``, ``threshold``) and of ``decentral ensemble`` (``method``, ``distributed``,
``loss``, ``tol``, ``check_every``), with the same meaning: the cell calls the functions those
commands call. ``seed`` seeds the ensemble and the localization, as the two commands do with
``--seed``. The metrics are the global and local RMS errors in module radii
(:func:`decentral.ensemble.evaluate`), the cost, and with ``distributed = true`` the messages per
module.
"""

from __future__ import annotations

import time
from typing import Any, Mapping

import numpy as np

from decentral.ensemble import EnsembleProblem, evaluate
from decentral.errors import InputError
from sims.runners.ensemble_run import distributed_config, localize
from sims.runners.ensemble_distributed import run_distributed
from sims.simulation.ensembles.generator import SHAPES, EnsembleSpec, generate
from sims.simulation.ensembles.sensors import SensorModel
from sims.io.validate import unknown_name
from sims.lab.study.options import Option, check_value, require

__all__ = ["OPTIONS", "METRICS", "normalize", "run"]

_METHODS = ("ncut", "incremental", "mds", "sdp", "bottom-up")


OPTIONS: dict[str, Option] = {
    "shape": Option("triple", str, help="a shape of `decentral make-ensemble`"),
    "n": Option(1000, int, valid=require(lambda v: v >= 2, "must be >= 2"), help="modules requested"),
    "seed": Option(0, int, help="seed of the ensemble and of the localization"),
    "radius": Option(0.05, float, valid=require(lambda v: v > 0, "must be positive"), help="module radius [m]"),
    "lattice": Option("hcp", str, ("hcp", "cubic"), help="3D lattice"),
    "jitter": Option(0.03, float, valid=require(lambda v: v >= 0, "must be >= 0"), help="3D lattice jitter [radii]"),
    "threshold": Option(0.2, float, valid=require(lambda v: 0 < v < 1, "must be in (0, 1)"),
                        help="IR detection threshold, fraction of peak"),
    "method": Option("ncut", str, _METHODS),
    "distributed": Option(False, bool, help="one agent per module over the simulated network"),
    "loss": Option(0.0, float, valid=require(lambda v: 0 <= v < 1, "must be in [0, 1)"),
                   help="distributed: probability that a message is dropped"),
    "tol": Option(None, float, valid=require(lambda v: v > 0, "must be positive"),
                  help="refinement tolerance: largest gradient entry [module radii] at every level"),
    "check_every": Option(None, int, valid=require(lambda v: v >= 1, "must be >= 1"),
                          help="distributed: refinement iterations between convergence checks"),
}

METRICS: dict[str, str] = {
    "global_rms": "RMS centre error after one rigid alignment [module radii]",
    "local_rms": "RMS centre error after aligning each small region [module radii]",
    "cost": "negative log-likelihood at the estimate",
    "messages_per_module": "mean messages sent per module (distributed)",
    "messages": "messages sent by all modules (distributed)",
    "levels": "depth of the hierarchy (distributed)",
    "solve_cpu_seconds": "CPU time of the localization alone (the cell's seconds also count making the ensemble) [s]",
    "n_modules": "modules generated (the largest connected part of n requested)",
    "observations": "observations (directed contacts)",
}


def normalize(params: Mapping[str, Any]) -> dict[str, Any]:
    """Check every key and value of one cell; return them normalized (raises :class:`InputError`)."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        if key not in OPTIONS:
            raise unknown_name(key, OPTIONS, "unknown key: neither make-ensemble nor the ensemble command knows it")
        out[key] = check_value(key, value, OPTIONS[key])
    shape = out.get("shape", OPTIONS["shape"].default)
    if shape not in tuple(SHAPES):
        raise InputError(f"unknown shape {shape!r}; known: {', '.join(tuple(SHAPES))}", field="shape")
    distributed = out.get("distributed", False)
    if "loss" in out and out["loss"] != 0.0 and not distributed:
        raise InputError("only applies with distributed = true", field="loss")
    if distributed and out.get("method", "ncut") != "ncut":
        raise InputError("distributed = true runs the ncut method only", field="method")
    if "check_every" in out and not distributed:
        raise InputError("only applies with distributed = true", field="check_every")
    return out


def _option(params: Mapping[str, Any], key: str) -> Any:
    return params.get(key, OPTIONS[key].default)


def _make(params: Mapping[str, Any]):
    spec = EnsembleSpec(_option(params, "shape"), _option(params, "n"), _option(params, "radius"),
                        _option(params, "lattice"), _option(params, "jitter"),
                        SensorModel(threshold=_option(params, "threshold")))
    ens = generate(spec, np.random.default_rng(_option(params, "seed")))
    return ens, EnsembleProblem.create(ens.dim, ens.n, ens.radius, ens.i, ens.j, ens.z)


def run(params: Mapping[str, Any]) -> dict[str, Any]:
    """Make, localize and score one cell; returns the :data:`METRICS` values."""
    ens, problem = _make(params)
    seed, tol = _option(params, "seed"), _option(params, "tol")
    metrics: dict[str, Any] = {"messages_per_module": None, "messages": None, "levels": None}
    t0 = time.process_time()
    if _option(params, "distributed"):
        config = distributed_config(_option(params, "loss"), tol, _option(params, "check_every"))
        res = run_distributed(problem, np.random.default_rng(seed), config)
        total = int(np.sum(res.messages))
        metrics.update(messages_per_module=total / problem.n, messages=total, levels=int(res.levels))
    else:
        res = localize(problem, _option(params, "method"), seed, tol)
    metrics["solve_cpu_seconds"] = time.process_time() - t0
    err = evaluate(res.estimate.position, ens.position, problem.pairs(), problem.radius)
    metrics.update(global_rms=err.global_rms, local_rms=err.local_rms, cost=float(res.cost),
                   n_modules=int(problem.n), observations=int(problem.num_observations))
    return metrics
