"""The ``localize`` cell: simulate a scenario (or take a recorded log), localize it, score the estimate.

The keys are the options of ``decentral localize`` (``window``, ``mode``, ``loss``, ``seed``,
``estimator``, ``solver``, ...; dashes become underscores) plus ``scenario`` and that scenario's own
parameters (those ``decentral simulate --set`` takes: ``n_assemblies``, ``steps``, ``pixel_sigma``,
...). ``seed`` seeds both the simulation and the simulated network; ``scenario_seed``, when given,
seeds the simulation alone (several network seeds on one log).

With ``log`` (a recorded ``decentral.log/1``) nothing is simulated: the cell localizes that log and,
with ``truth`` (a ``decentral.truth/1``, or ``"beside"`` for the ``truth.json`` in the log's folder
that ``decentral simulate`` writes), scores it; without truth, the metrics that need it are NULL.
The files are read and validated once, on the machine that runs the study (:func:`inputs`), and
their text travels to the cell with it (:mod:`sims.lab.study.engines`), so no node needs the files.
"""

from __future__ import annotations

import hashlib
import importlib
import time
from dataclasses import fields
from pathlib import Path
from typing import Any, Mapping

from decentral.bearing import BearingConfig, estimate_log_bearing
from decentral.errors import InputError
from decentral.estimator import EstimatorConfig, estimate_log
from decentral.factors import NoiseModel
from decentral.metrics import score_estimate
from sims.runners.admm_run import AdmmRunConfig, run_admm
from sims.io.validate import unknown_name
from sims.simulation.scenarios import SCENARIOS, get_scenario, simulate
from sims.lab.study.cells import ROW_STATUS
from sims.lab.study.options import Option, check_value, require
from sims.simulation.world.sensors import SensorNoise

__all__ = ["OPTIONS", "METRICS", "FILE_KEYS", "TRUTH_BESIDE", "normalize", "inputs", "run"]

#: keys whose values are input files: read on the driver, shipped to the cell as text
FILE_KEYS = ("log", "truth")
#: ``truth = "beside"``: the ``truth.json`` in each log's folder (the layout ``decentral simulate`` writes)
TRUTH_BESIDE = "beside"

_positive = require(lambda v: v > 0, "must be positive")
_probability = require(lambda v: 0.0 <= v < 1.0, "must be in [0, 1)")

#: the localize command's own keys (scenario keys come from the scenario's config)
OPTIONS: dict[str, Option] = {
    "scenario": Option("table1", str, help="a scenario of `decentral simulate`"),
    "log": Option(None, str, help="a recorded decentral.log/1 to localize instead of simulating"),
    "truth": Option(None, str, help=f"the log's decentral.truth/1, or {TRUTH_BESIDE!r}: truth.json beside the log"),
    "seed": Option(0, int, help="seed of the simulation and of the simulated network"),
    "scenario_seed": Option(None, int, help="seed of the simulation only (default: seed)"),
    "window": Option(5, int, valid=require(lambda v: v >= 1, "must be >= 1"), help="steps per window K"),
    "reference": Option(None, str, help="reference assembly (default: the first)"),
    "mode": Option("centralized", str, ("centralized", "admm")),
    "loss": Option(0.0, float, valid=_probability, help="admm: probability that a message is dropped"),
    "estimator": Option("windowed", str, ("windowed", "bearing")),
    "solver": Option("low-rank", str, ("low-rank", "sdp")),
    "weighting": Option("information", str, ("information", "unit")),
    "share_forms": Option("every", str, ("every", "first", "never")),
    "aggregation": Option("tree", str, ("tree", "broadcast")),
    "max_rounds": Option(300, int, valid=require(lambda v: v >= 1, "must be >= 1")),
    "sigma_pixel": Option(NoiseModel.sigma_pixel, float, valid=_positive),
    "sigma_radius": Option(NoiseModel.sigma_radius, float, valid=_positive),
    "sigma_odom_p": Option(NoiseModel.sigma_odom_p, float, valid=_positive),
    "sigma_odom_theta": Option(NoiseModel.sigma_odom_theta, float, valid=_positive),
}

#: metric columns, in table order (NULL where a metric does not apply, e.g. messages when centralized)
METRICS: dict[str, str] = {
    "pos_error_m": "mean position error of the placed assemblies [m]",
    "rel_error_pct": "mean position error relative to distance [%]",
    "angle_error_deg": "mean yaw error [deg]",
    "coverage": "fraction of (step, assembly) pairs placed",
    "messages": "messages sent by all agents (admm)",
    "bytes": "bytes sent by all agents (admm)",
    "rounds": "ADMM rounds over all steps (admm)",
    "converged": "1 when every agent converged at every step (admm)",
    "certified": "fraction of windows certified globally optimal (windowed estimator)",
    "solve_cpu_seconds": "CPU time of the localization alone (the cell's seconds also count the simulation) [s]",
}


def _scenario_defaults(name: str) -> dict[str, Any]:
    cls = importlib.import_module(SCENARIOS[name]).SCENARIO
    noise = {f.name: f.default for f in fields(SensorNoise)}
    own = {f.name: f.default for f in fields(cls.Config) if f.name != "sensors"}
    return {**noise, **own}


def normalize(params: Mapping[str, Any]) -> dict[str, Any]:
    """Check every key and value of one cell; return them normalized (raises :class:`InputError`).

    Scenario keys are checked by building the scenario (cheap: no simulation runs).
    """
    if "log" in params:
        return _normalize_recorded(params)
    if "truth" in params:
        raise InputError("only applies with log = \"PATH\" (a simulated cell is scored against its own truth)",
                         field="truth")
    scenario = check_value("scenario", params.get("scenario", OPTIONS["scenario"].default), OPTIONS["scenario"])
    if scenario not in SCENARIOS:
        raise InputError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}", field="scenario")
    scenario_defaults = _scenario_defaults(scenario)
    out: dict[str, Any] = {}
    for key, value in params.items():
        if key in OPTIONS:
            out[key] = check_value(key, value, OPTIONS[key])
        elif key in scenario_defaults:
            default = scenario_defaults[key]
            if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            out[key] = value
        else:
            raise unknown_name(key, [*OPTIONS, *scenario_defaults],
                               f"unknown key: neither scenario {scenario!r} nor the localize command knows it")
    get_scenario(scenario, **_scenario_params(out))
    # unlike `decentral localize` (which refuses an option its mode ignores), a cell accepts the network
    # options (loss, share_forms, ...) in centralized mode, where they change nothing: a grid may cross
    # mode with loss, and its centralized cells are then repeated per loss value (docs/studies.md)
    if out.get("mode") == "admm" and out.get("estimator", "windowed") != "windowed":
        raise InputError("mode = \"admm\" runs the windowed estimator only", field="estimator")
    return out


def _normalize_recorded(params: Mapping[str, Any]) -> dict[str, Any]:
    """Normalize the keys of a cell over a recorded log: localize options only, nothing simulated."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        if key in ("scenario", "scenario_seed"):
            raise InputError("does not apply with log = \"PATH\": a recorded log is not simulated", field=key)
        if key not in OPTIONS:
            raise InputError("unknown key: the localize command does not know it (and with log = \"PATH\" "
                             "nothing is simulated, so scenario keys do not apply)", field=key)
        out[key] = check_value(key, value, OPTIONS[key])
    if out.get("mode") == "admm" and out.get("estimator", "windowed") != "windowed":
        raise InputError("mode = \"admm\" runs the windowed estimator only", field="estimator")
    return out


def _read(path: Path, field: str) -> str:
    from sims.io.text import read_text

    try:
        return read_text(path)
    except InputError as err:
        raise InputError(f"{err.message} (the study's {field} key names it)", source=err.source or str(path),
                         field=err.field) from None


def _truth_path(log: str, truth: str, base: Path) -> Path:
    return (base / log).parent / "truth.json" if truth == TRUTH_BESIDE else base / truth


def inputs(params: Mapping[str, Any], base: Path, cache: dict | None = None) -> dict[str, str]:
    """Read and validate the files a cell needs; returns their texts by key (``log``, ``truth``).

    Runs on the driver, before any cell: a missing file, a file that is not a valid
    ``decentral.log/1`` or ``decentral.truth/1``, or a truth without a log's assembly raises
    :class:`InputError` naming the file and the field. Paths are relative to ``base`` (the spec's
    folder). ``cache`` (path -> text) saves reading a file once per cell.
    """
    if "log" not in params:
        return {}
    cache = {} if cache is None else cache
    out = {}
    log_path = base / params["log"]
    if log_path not in cache:
        cache[log_path] = _read(log_path, "log")
        _parse_log(cache[log_path], str(log_path))
    out["log"] = cache[log_path]
    if params.get("truth") is not None:
        truth_path = _truth_path(params["log"], params["truth"], base)
        if truth_path not in cache:
            cache[truth_path] = _read(truth_path, "truth")
            truth = _parse_truth(cache[truth_path], str(truth_path))
            missing = sorted(set(_parse_log(cache[log_path], str(log_path)).assemblies) - set(truth.poses.p))
            if missing:
                raise InputError(f"has no poses of {', '.join(missing)}, an assembly of {log_path}: is it the truth "
                                 "of that log?", source=str(truth_path), field="steps[0].poses")
        out["truth"] = cache[truth_path]
    return out


def digest(texts: Mapping[str, str]) -> dict[str, str]:
    """SHA-256 (16 hex digits) of each input text: part of the cell's identity, so a changed file is a new cell."""
    return {f"{k}_sha256": hashlib.sha256(v.encode()).hexdigest()[:16] for k, v in sorted(texts.items())}


def _parse_log(text: str, source: str):
    from sims.io.jsonfile import loads_json
    from sims.io.log_json import parse_log

    try:
        return parse_log(loads_json(text, source))
    except InputError as err:
        raise err.located(source) from None


def _parse_truth(text: str, source: str):
    from sims.io.jsonfile import loads_json
    from sims.simulation.world.truth import parse_truth

    try:
        return parse_truth(loads_json(text, source))
    except InputError as err:
        raise err.located(source) from None


def _scenario_params(params: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in params.items() if k not in OPTIONS}


def _option(params: Mapping[str, Any], key: str) -> Any:
    return params.get(key, OPTIONS[key].default)


def run(params: Mapping[str, Any], texts: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Simulate (or parse ``texts["log"]``), localize and score one cell; returns the :data:`METRICS` values.

    ``texts`` holds the input files' contents (:func:`inputs`) when the cell has ``log``.
    """
    seed = _option(params, "seed")
    if "log" in params:
        if not texts or "log" not in texts:
            raise InputError("the recorded log's text did not reach this cell", field="log")
        log = _parse_log(texts["log"], params["log"])
        truth = _parse_truth(texts["truth"], str(params["truth"])).poses if "truth" in texts else None
        where = params["log"]
    else:
        scenario = get_scenario(_option(params, "scenario"), **_scenario_params(params))
        sim = simulate(scenario, seed=params.get("scenario_seed", seed))
        log, truth, where = sim.log, sim.truth.poses, "the simulated log"
    reference = params.get("reference") or log.assemblies[0]
    if reference not in log.assemblies:
        raise InputError(f"no assembly {reference!r} in {where}", field="reference")
    t0 = time.process_time()
    estimate = _localize(log, params, reference, seed)
    solve_cpu_seconds = time.process_time() - t0
    if truth is not None:
        overall = score_estimate(truth, estimate).overall.to_dict()
    else:  # no truth: only what the estimate itself tells
        overall = {"position_m": None, "relative_position_pct": None, "yaw_deg": None,
                   "coverage": _coverage(estimate, log.assemblies)}
    stats = estimate.stats
    metrics = {
        "pos_error_m": overall["position_m"],
        "rel_error_pct": overall["relative_position_pct"],
        "angle_error_deg": overall["yaw_deg"],
        "coverage": overall["coverage"],
        "messages": None, "bytes": None, "rounds": None, "converged": None, "certified": None,
        "solve_cpu_seconds": solve_cpu_seconds,
    }
    if stats.get("mode") == "admm":
        total = stats["messages"]["total"]
        metrics.update(messages=total["sent"], bytes=total["bytes_sent"], rounds=stats["rounds_total"],
                       converged=int(stats["all_converged"]))
        metrics[ROW_STATUS] = stats.get("status", "ok")  # 'degraded': the row says so (sims.runners.run_status); its metrics stand
    elif "certified_windows" in stats and stats.get("windows_solved"):
        metrics["certified"] = stats["certified_windows"] / stats["windows_solved"]
    return metrics


def _coverage(estimate, assemblies) -> float:
    """Fraction of (step, assembly other than the reference) pairs the estimate places (no truth needed)."""
    others = [a for a in assemblies if a != estimate.reference]
    pairs = len(estimate.steps) * len(others)
    placed = sum(1 for step in estimate.steps for a in others if a in step.poses)
    return placed / pairs if pairs else 0.0


def _localize(log, params: Mapping[str, Any], reference: str, seed: int):
    """The estimate ``decentral localize`` would write for these options."""
    noise = NoiseModel(_option(params, "sigma_pixel"), _option(params, "sigma_radius"),
                       _option(params, "sigma_odom_p"), _option(params, "sigma_odom_theta"),
                       _option(params, "weighting"))
    window = _option(params, "window")
    if _option(params, "mode") == "admm":
        config = AdmmRunConfig(window=window, noise=noise, loss=_option(params, "loss"),
                               share_forms=_option(params, "share_forms"),
                               aggregation=_option(params, "aggregation"), max_rounds=_option(params, "max_rounds"))
        return run_admm(log, reference, config, seed=seed).estimate
    if _option(params, "estimator") == "bearing":
        return estimate_log_bearing(log, BearingConfig(window=window, noise=noise), reference)
    return estimate_log(log, EstimatorConfig(window=window, solver=_option(params, "solver"), noise=noise), reference)
