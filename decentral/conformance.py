"""Conformance check of a relative-pose estimator: :func:`estimator_test` drives one through its contract.

An estimator is any callable ``fn(log, config=..., reference=...) -> Estimate`` (the centralized
:func:`decentral.estimator.estimate_log`, the bearing baseline, the decentralized runner wrapped to
return its estimate, or your own). The check runs it on small exact logs (:mod:`decentral.synthetic`)
and raises :class:`AssertionError` with a message saying what to fix at the first broken rule, in the
manner of PettingZoo's ``parallel_api_test``.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from typing import Any, Callable

import numpy as np

from decentral.errors import DecentralError
from decentral.geometry import wrap_angle
from decentral.observations import Detection, Estimate, ObservationLog, PlanarPose
from decentral.unplaced import REASONS, count_reasons
from decentral.synthetic import camera, circle_motion, l_config, make_log, true_relative

__all__ = ["REQUIRED_STATS", "conformance_log", "estimator_test"]

#: the ``stats`` keys every estimator's estimate carries (the rest is the estimator's own)
REQUIRED_STATS = ("estimator", "window", "unplaced", "stray_detections", "seconds")

#: node id of the stray tag :func:`conformance_log` adds (a node of no assembly)
_STRAY = 900


def _require(ok: bool, name: str, message: str) -> None:
    if not ok:
        raise AssertionError(f"estimator_test({name}): {message}")


def conformance_log(steps: int = 4) -> tuple[ObservationLog, dict]:
    """Three assemblies on a circle, the first seeing the other two with two cameras, noiseless.

    One stray tag (node id 900, in no configuration) is seen at step 1. Returns the log and its world
    poses ``world[name][k] = (yaw, p)`` for :func:`decentral.synthetic.true_relative`.

    Examples
    --------
    >>> log, world = conformance_log()
    >>> log.assemblies, len(log.steps), sum(step.stray_detections() for step in log.steps)
    (('A', 'B', 'C'), 4, 1)
    """
    world = {name: circle_motion(steps, (0.0, 0.0), 1.0, phase, 0.1, 0.0)
             for name, phase in (("A", 0.0), ("B", 0.8), ("C", 1.6))}
    configs = {"A": l_config([0, 1, 2, 3]), "B": l_config([10, 11, 12, 13]), "C": l_config([20, 21, 22, 23])}
    cams = [camera("A", yaw=0.5), camera("A", "cam1", yaw=1.0), camera("B", yaw=0.5), camera("C", yaw=-0.5)]
    log = make_log(world, configs, cams)
    step = log.steps[1]
    key = "A/cam0"
    dets = step.detections[key] + (Detection(_STRAY, 500.0, 380.0, 12.0),)
    stepped = replace(step, detections={**step.detections, key: dets})
    log = replace(log, steps=log.steps[:1] + (stepped,) + log.steps[2:])
    return log, world


def _call(fn: Callable[..., Estimate], log: Any, config: Any, reference: str | None) -> Estimate:
    kwargs: dict = {"reference": reference}
    if config is not None:
        kwargs["config"] = config
    return fn(log, **kwargs)


def _timeless(value: Any) -> Any:
    """``value`` without its wall-clock entries (keys naming seconds), which differ from run to run."""
    if isinstance(value, dict):
        return {k: _timeless(v) for k, v in value.items() if "seconds" not in str(k)}
    if isinstance(value, (list, tuple)):
        return [_timeless(v) for v in value]
    return value


def estimator_test(fn: Callable[..., Estimate], config: Any = None, *, name: str | None = None,
                   position_tol: float = 0.05, yaw_tol: float = math.radians(2.0)) -> None:
    """Check that ``fn`` behaves as an estimator of relative poses; raise ``AssertionError`` if not.

    The rules, in the order checked: it refuses a log that is not an :class:`ObservationLog` with a
    :class:`~decentral.errors.DecentralError` (not a crash); it returns an :class:`Estimate` in the frame
    of the reference it was given, one step per log step at the log's times; every other assembly is
    either placed (a finite :class:`PlanarPose`) or listed in ``unplaced`` with a code of
    :data:`decentral.unplaced.REASONS`, never both; ``stats`` holds :data:`REQUIRED_STATS`, with
    ``unplaced`` the count of the steps' reasons and ``stray_detections`` the log's stray tags, and is
    JSON-serializable without NaN; on a noiseless log every placed pose is within ``position_tol`` (m)
    and ``yaw_tol`` (rad) of the truth; and the same input gives the same estimate.

    Parameters
    ----------
    fn : callable
        ``fn(log, config=config, reference=reference) -> Estimate`` (``config`` left out when None).
    config : object, optional
        The estimator's configuration; None: its default.
    name : str, optional
        Name used in the failure messages (default: ``fn.__name__``).
    position_tol, yaw_tol : float
        Accuracy asked for on the noiseless log.

    Examples
    --------
    >>> from decentral.estimator import EstimatorConfig, estimate_log
    >>> estimator_test(estimate_log, EstimatorConfig(window=3))  # passes: returns None
    """
    name = name or getattr(fn, "__name__", repr(fn))
    log, world = conformance_log()
    try:
        _call(fn, {"assemblies": ["A"]}, config, None)
    except DecentralError:
        pass
    except Exception as exc:  # noqa: BLE001 - the point is to report which exception escaped
        raise AssertionError(f"estimator_test({name}): a dict instead of an ObservationLog raised "
                             f"{type(exc).__name__} ({exc}); refuse bad input with decentral.errors.InputError "
                             f"(decentral.observations.require_log does this)") from exc
    else:
        raise AssertionError(f"estimator_test({name}): accepted a dict as its log; call "
                             f"decentral.observations.require_log(log) first")

    for reference in ("A", "B"):
        est = _call(fn, log, config, reference)
        _require(isinstance(est, Estimate), name, f"returned {type(est).__name__}, not a decentral.observations.Estimate")
        _require(est.reference == reference, name,
                 f"asked for reference {reference!r}, the estimate says {est.reference!r}")
        _require(len(est.steps) == len(log.steps), name,
                 f"{len(est.steps)} estimate steps for {len(log.steps)} log steps: give one step per log step")
        others = [a for a in log.assemblies if a != reference]
        for k, (step, logged) in enumerate(zip(est.steps, log.steps)):
            _require(step.t == logged.t, name, f"step {k} has t={step.t}, the log's is {logged.t}: keep the log's times")
            _require(reference not in step.poses, name, f"step {k} places the reference itself; leave it out")
            for a in others:
                placed, why = a in step.poses, step.unplaced.get(a)
                _require(placed != (why is not None), name,
                         f"step {k}: assembly {a!r} must be either placed or given an unplaced reason, not "
                         f"{'both' if placed else 'neither'}")
                _require(why is None or why in REASONS, name,
                         f"step {k}: unplaced reason {why!r} of {a!r} is not one of decentral.unplaced.REASONS")
            for a, pose in step.poses.items():
                _require(a in others, name, f"step {k} places {a!r}, which is not an assembly of the log")
                _require(isinstance(pose, PlanarPose), name, f"step {k}: the pose of {a!r} is not a PlanarPose")
                p = np.asarray(pose.p, dtype=float)
                _require(p.shape == (3,) and bool(np.all(np.isfinite(p))) and math.isfinite(pose.theta), name,
                         f"step {k}: the pose of {a!r} is not finite with p of shape (3,); never return NaN as an "
                         f"answer, list the assembly in unplaced instead")
                p_true, th_true = true_relative(world, a, reference, k)
                dp = float(np.linalg.norm(p - p_true))
                dth = abs(float(wrap_angle(pose.theta - th_true)))
                _require(dp <= position_tol and dth <= yaw_tol, name,
                         f"step {k}: on a noiseless log {a!r} is {dp:.3g} m and {math.degrees(dth):.3g} deg off the "
                         f"truth (allowed {position_tol} m, {math.degrees(yaw_tol):.3g} deg): a pose is the target's root frame "
                         f"in the reference's root frame")
        _require(any(step.poses for step in est.steps), name,
                 "placed no assembly at any step of a noiseless log where the reference sees both others")
        missing = [key for key in REQUIRED_STATS if key not in est.stats]
        _require(not missing, name, f"stats lacks {missing}: every estimator reports {list(REQUIRED_STATS)}")
        counted = count_reasons(step.unplaced for step in est.steps)
        _require(dict(est.stats["unplaced"]) == counted, name,
                 f"stats['unplaced'] is {est.stats['unplaced']}, the steps' reasons count {counted} "
                 f"(decentral.unplaced.count_reasons)")
        stray = sum(step.stray_detections() for step in log.steps)
        _require(est.stats["stray_detections"] == stray, name,
                 f"stats['stray_detections'] is {est.stats['stray_detections']}, the log has {stray} stray tag(s)")
        try:
            json.dumps(est.stats, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise AssertionError(f"estimator_test({name}): stats must be JSON-serializable without NaN "
                                 f"(plain numbers, strings, lists and dicts): {exc}") from exc
    again = _call(fn, log, config, "B")
    same = all(a.poses.keys() == b.poses.keys() and a.unplaced == b.unplaced
               and all(np.array_equal(a.poses[n].p, b.poses[n].p) and a.poses[n].theta == b.poses[n].theta
                       for n in a.poses)
               for a, b in zip(est.steps, again.steps))
    _require(same and _timeless(est.stats) == _timeless(again.stats), name,
             "two runs on the same input differ: take randomness from a seeded argument, never the global state")
