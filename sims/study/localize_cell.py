"""The ``localize`` cell: simulate a scenario, localize its log, score the estimate against truth.

The keys are the options of ``decentral localize`` (``window``, ``mode``, ``loss``, ``seed``,
``estimator``, ``solver``, ...; dashes become underscores) plus ``scenario`` and that scenario's own
parameters (those ``decentral simulate --set`` takes: ``n_assemblies``, ``steps``, ``pixel_sigma``,
...). ``seed`` seeds both the simulation and the simulated network; ``scenario_seed``, when given,
seeds the simulation alone (several network seeds on one log).
"""

from __future__ import annotations

import importlib
import time
from dataclasses import fields
from typing import Any, Mapping

from decentral.bearing import BearingConfig, estimate_log_bearing
from decentral.errors import InputError
from decentral.estimator import EstimatorConfig, estimate_log
from decentral.factors import NoiseModel
from decentral.metrics import score_estimate
from sims.admm_run import AdmmRunConfig, run_admm
from sims.scenarios import SCENARIOS, get_scenario, simulate
from sims.study.cells import ROW_STATUS
from sims.study.options import Option, check_value, require
from sims.world.sensors import SensorNoise

__all__ = ["OPTIONS", "METRICS", "normalize", "run"]

_positive = require(lambda v: v > 0, "must be positive")
_probability = require(lambda v: 0.0 <= v < 1.0, "must be in [0, 1)")

#: the localize command's own keys (scenario keys come from the scenario's config)
OPTIONS: dict[str, Option] = {
    "scenario": Option("table1", str, help="a scenario of `decentral simulate`"),
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
            raise InputError(f"unknown key: neither scenario {scenario!r} nor the localize command knows it",
                             field=key)
    get_scenario(scenario, **_scenario_params(out))
    # unlike `decentral localize` (which refuses an option its mode ignores), a cell accepts the network
    # options (loss, share_forms, ...) in centralized mode, where they change nothing: a grid may cross
    # mode with loss, and its centralized cells are then repeated per loss value (docs/studies.md)
    if out.get("mode") == "admm" and out.get("estimator", "windowed") != "windowed":
        raise InputError("mode = \"admm\" runs the windowed estimator only", field="estimator")
    return out


def _scenario_params(params: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in params.items() if k not in OPTIONS}


def _option(params: Mapping[str, Any], key: str) -> Any:
    return params.get(key, OPTIONS[key].default)


def run(params: Mapping[str, Any]) -> dict[str, Any]:
    """Simulate, localize and score one cell; returns the :data:`METRICS` values."""
    scenario = get_scenario(_option(params, "scenario"), **_scenario_params(params))
    seed = _option(params, "seed")
    sim_seed = params.get("scenario_seed", seed)
    sim = simulate(scenario, seed=sim_seed)
    log = sim.log
    reference = params.get("reference") or log.assemblies[0]
    if reference not in log.assemblies:
        raise InputError(f"no assembly {reference!r} in the simulated log", field="reference")
    t0 = time.process_time()
    estimate = _localize(log, params, reference, seed)
    solve_cpu_seconds = time.process_time() - t0
    overall = score_estimate(sim.truth.poses, estimate).overall.to_dict()
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
        if stats.get("status", "ok") != "ok":
            metrics[ROW_STATUS] = "degraded"  # the row says so (sims.run_status); its metrics stand
    elif "certified_windows" in stats and stats.get("windows_solved"):
        metrics["certified"] = stats["certified_windows"] / stats["windows_solved"]
    return metrics


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
