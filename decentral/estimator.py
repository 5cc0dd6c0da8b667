"""Liu et al.'s windowed relative-pose estimator, for any number of assemblies and cameras.

For every step ``k`` of a log, the window ``[k-K+1, k]`` is built (:mod:`decentral.window`), the
positions are eliminated and the rotation relaxation solved (:mod:`decentral.relaxation`), and
every assembly that the window places relative to the reference is reported at step ``k`` by
Liu et al. 2024 eq. (19):

.. math:: R_{H_1}^{H_0} = R_{H_0}^T R_{H_1}, \\qquad p_{H_1}^{H_0} = R_{H_0}^T (p_{H_1} - p_{H_0}).

An assembly is placed only when the window determines it: it is connected to the reference by
factors, and its yaw relative to the reference is not in the null space of the yaw Hessian beyond
the global gauge (an unobservable yaw, e.g. a one-node target that does not move) and has a
Laplace-approximate standard deviation below ``max_yaw_std``.
"""

from __future__ import annotations

import time
from typing import Callable
from dataclasses import dataclass, field

import numpy as np

from decentral.errors import InputError
from decentral.factors import NoiseModel, StepMeasurements, measure_log
from decentral.geometry import wrap_angle
from decentral.observations import Estimate, EstimateStep, ObservationLog, PlanarPose, require_log, resolve_reference
from decentral.unplaced import count_reasons, unplaced_reasons
from decentral.relaxation import RelaxationResult, recover_positions, reduce_rotations, solve_relaxation, yaw_hessian
from decentral.window import WindowProblem, build_window

__all__ = ["EstimatorConfig", "WindowEstimate", "solve_window", "estimate_log", "placeable_yaws"]

#: eigenvalues of the yaw Hessian below this fraction of its largest are treated as exact zeros
NULL_TOL = 1e-9


@dataclass(frozen=True)
class EstimatorConfig:
    """Parameters of the windowed estimator.

    Attributes
    ----------
    window : int
        Number of steps K in the sliding window (1 = per-frame fit). Liu et al. 2024 uses K = 5.
    solver : {"low-rank", "sdp"}
        Low-rank with certificate (SDP fallback) or the cvxpy/Clarabel reference.
    noise : NoiseModel
        Factor weights.
    max_yaw_std : float
        Largest Laplace-approximate relative-yaw standard deviation (rad) at which an assembly is
        still placed. Applied with information weights only: with unit weights the cost is not a
        negative log-likelihood, so only the exact null-space test decides.
    warm_start : bool
        Start each window's solve from the previous window's yaws.
    """

    window: int = 5
    solver: str = "low-rank"
    noise: NoiseModel = field(default_factory=NoiseModel)
    max_yaw_std: float = 1.0
    warm_start: bool = True

    def __post_init__(self) -> None:
        if not (isinstance(self.window, int) and self.window >= 1):
            raise InputError(f"window must be an integer >= 1, got {self.window!r}", field="window")
        if self.solver not in ("low-rank", "sdp"):
            raise InputError(f"solver must be 'low-rank' or 'sdp', got {self.solver!r}", field="solver")
        if not self.max_yaw_std > 0:
            raise InputError("max_yaw_std must be positive", field="max_yaw_std")


@dataclass(frozen=True)
class WindowEstimate:
    """One solved window: world-gauge poses of every variable and what can be placed.

    ``theta`` (m,) and ``position`` (m, 3) are in the window's arbitrary gauge; ``placeable`` lists
    the variable keys whose pose relative to the reference at the same step is determined.
    """

    problem: WindowProblem
    relaxation: RelaxationResult
    theta: np.ndarray
    position: np.ndarray
    placeable: frozenset
    yaw_std: dict

    def relative(self, key: tuple[str, int], reference: tuple[str, int]) -> PlanarPose:
        """Pose of variable ``key`` in the frame of ``reference`` (Liu et al. 2024 eq. (19))."""
        index = self.problem.index()
        i, r = index[key], index[reference]
        c, s = np.cos(self.theta[r]), np.sin(self.theta[r])
        d = self.position[i] - self.position[r]
        p = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]])  # R_ref^T (p - p_ref)
        return PlanarPose(p, float(wrap_angle(self.theta[i] - self.theta[r])))


def placeable_yaws(Q: np.ndarray, theta: np.ndarray, index: dict, reference: tuple[str, int],
                   max_yaw_std: float) -> tuple[frozenset, dict]:
    """Keys at the reference's step whose yaw relative to it is determined, and their yaw std (rad).

    Parameters
    ----------
    Q : ndarray, shape (2m, 2m)
        The rotation-only cost after eliminating positions (Liu et al. 2024 eq. (14)).
    theta : ndarray, shape (m,)
        The yaws at the optimum (any common offset: the test looks at differences only).
    index : dict
        ``(assembly, step)`` key -> variable index into ``theta``.
    reference : tuple
        The reference key; only keys of its step are tested.
    max_yaw_std : float
        Largest Laplace-approximate yaw standard deviation that still places (rad).
    """
    H = yaw_hessian(Q, theta)
    lam, V = np.linalg.eigh(0.5 * (H + H.T))
    scale = max(np.abs(lam).max(), 1e-300)
    null = V[:, lam < NULL_TOL * scale]  # always holds the gauge (all ones)
    r = index[reference]
    inv = np.where(lam >= NULL_TOL * scale, 1.0 / np.where(lam > 0, lam, 1.0), 0.0)
    placed, stds = set(), {}
    for key, i in index.items():
        if key[1] != reference[1] or key == reference:
            continue
        d = np.zeros(len(theta))
        d[i], d[r] = 1.0, -1.0
        if np.abs(null.T @ d).max(initial=0.0) > 1e-6:
            continue  # the relative yaw moves along a non-gauge null direction: not determined
        coords = V.T @ d
        var = 2.0 * float(np.sum(inv * coords**2))  # Fisher information of a chi-square cost is H/2
        std = float(np.sqrt(max(var, 0.0)))
        stds[key[0]] = std
        if std <= max_yaw_std:
            placed.add(key)
    return frozenset(placed), stds


def solve_window(problem: WindowProblem, reference: tuple[str, int], config: EstimatorConfig,
                 theta0: np.ndarray | None = None) -> WindowEstimate:
    """Eliminate positions, solve the relaxation, recover positions and decide what is placeable."""
    Q = reduce_rotations(problem.M, problem.m)
    result = solve_relaxation(Q, config.solver, theta0)
    position = recover_positions(problem.M, result.theta, problem.b_z)  # Liu et al. 2024 eq. (18)
    limit = config.max_yaw_std if config.noise.weighting == "information" else np.inf
    placeable, stds = placeable_yaws(Q, result.theta, problem.index(), reference, limit)
    return WindowEstimate(problem, result, result.theta, position, placeable, stds)


def _warm_start(previous: WindowEstimate | None, problem: WindowProblem,
                measurements: list[StepMeasurements]) -> np.ndarray | None:
    """Yaws of the previous window for shared variables, propagated by odometry for new ones."""
    if previous is None:
        return None
    prev = {key: previous.theta[i] for i, key in enumerate(previous.problem.variables)}
    theta = np.empty(problem.m)
    for i, (name, k) in enumerate(problem.variables):
        if (name, k) in prev:
            theta[i] = prev[(name, k)]
        elif (name, k - 1) in prev and name in measurements[k].odometry:
            theta[i] = prev[(name, k - 1)] + measurements[k].odometry[name].dtheta
            prev[(name, k)] = theta[i]
        else:
            return None
    return theta


def estimate_log(log: ObservationLog, config: EstimatorConfig = EstimatorConfig(),
                 reference: str | None = None, progress: Callable[..., None] | None = None) -> Estimate:
    """Run the windowed estimator over a whole log (the centralized joint estimate).

    Parameters
    ----------
    log : ObservationLog
        The observations (never ground truth).
    config : EstimatorConfig
        Window length, solver and weights.
    reference : str, optional
        Assembly whose root frame the poses are written in; defaults to the first listed.
    progress : callable, optional
        Called after each step as ``progress(steps_done, steps_total, certified=n)`` (``n``: windows
        certified so far); the library itself never prints.

    Returns
    -------
    Estimate
        Per step, the poses of every placeable assembly and, in ``unplaced``, why each other one is
        not placed; ``stats`` reports certificates, solver use, skipped detections, reason counts
        (``stats["unplaced"]``) and timings.

    Raises
    ------
    InputError
        If ``log`` is not a well-formed :class:`ObservationLog` (e.g. a decoded JSON dict: read files
        with :func:`sims.io.log_json.read_log`), ``config`` not an :class:`EstimatorConfig`, or
        ``reference`` not one of its assemblies.

    Examples
    --------
    Two assemblies on a circle, ``A``'s camera seeing ``B``'s nodes (an exact log of
    :mod:`decentral.synthetic`); ``B``'s pose in ``A``'s root frame at every step:

    >>> from decentral.synthetic import camera, circle_motion, l_config, make_log
    >>> world = {"A": circle_motion(3, (0, 0), 1.0, 0.0, 0.1, 0.0), "B": circle_motion(3, (0, 0), 1.0, 0.8, 0.1, 0.0)}
    >>> log = make_log(world, {"A": l_config([0, 1, 2, 3]), "B": l_config([10, 11, 12, 13])}, [camera("A", yaw=0.5)])
    >>> est = estimate_log(log, EstimatorConfig(window=3))
    >>> [sorted(step.poses) for step in est.steps], est.stats["all_certified"]
    ([['B'], ['B'], ['B']], True)
    >>> from decentral.synthetic import true_relative
    >>> p, theta = true_relative(world, "B", "A", 2)
    >>> bool(np.allclose(est.steps[2].poses["B"].p, p, atol=1e-6))
    True
    """
    log = require_log(log)
    if not isinstance(config, EstimatorConfig):
        raise InputError(f"expected an EstimatorConfig, got {type(config).__name__}", field="config")
    reference = resolve_reference(log, reference)
    start = time.perf_counter()
    measurements = measure_log(log, config.noise)
    steps, windows = [], []
    previous = None
    for k in range(len(measurements)):
        span = range(max(0, k - config.window + 1), k + 1)
        problem = build_window(measurements, span, reference)
        poses: dict[str, PlanarPose] = {}
        connected, usable, yaw_std = set(), False, {}
        if problem is not None:
            theta0 = _warm_start(previous, problem, measurements) if config.warm_start else None
            solved = solve_window(problem, (reference, k), config, theta0)
            usable = solved.relaxation.status in ("optimal", "optimal_inaccurate", "uncertified")
            for key in sorted(solved.placeable) if usable else ():
                poses[key[0]] = solved.relative(key, (reference, k))
            connected = {name for name, step in problem.variables if step == k}
            yaw_std = solved.yaw_std
            windows.append(_window_stats(k, solved))
            previous = solved
        else:
            previous = None
        seen = {name for j in span for name in measurements[j].visual.observer + measurements[j].visual.target}
        unplaced = unplaced_reasons(log.assemblies, reference, poses, with_data=seen, connected=connected,
                                    solved=usable, yaw_std=yaw_std)
        steps.append(EstimateStep(measurements[k].t, poses, unplaced))
        if progress is not None:
            progress(k + 1, len(measurements), certified=sum(w["certified"] for w in windows))
    stats = _summary(measurements, windows, config, time.perf_counter() - start)
    stats["unplaced"] = count_reasons(step.unplaced for step in steps)
    return Estimate(reference, tuple(steps), stats)


def _window_stats(k: int, solved: WindowEstimate) -> dict:
    res = solved.relaxation
    return {
        "step": k,
        "variables": solved.problem.m,
        "certified": res.certified,
        "min_eig": res.min_eig,
        "solver": res.solver,
        "status": res.status,
        "iterations": res.iterations,
        "cost": res.cost,
        "seconds": res.seconds,
        "yaw_std": {name: round(std, 6) for name, std in solved.yaw_std.items()},
    }


def _summary(measurements: list[StepMeasurements], windows: list[dict], config: EstimatorConfig,
             seconds: float) -> dict:
    certified = [w["certified"] for w in windows]
    solvers: dict[str, int] = {}
    for w in windows:
        solvers[w["solver"]] = solvers.get(w["solver"], 0) + 1
    return {
        "estimator": "windowed-relaxation",
        "window": config.window,
        "solver": config.solver,
        "weighting": config.noise.weighting,
        "windows_solved": len(windows),
        "certified_windows": int(sum(certified)),
        "all_certified": bool(all(certified)) if certified else False,
        "solver_use": solvers,
        "stray_detections": int(sum(m.stray for m in measurements)),
        "self_detections": int(sum(m.self_seen for m in measurements)),
        "seconds": seconds,
        "windows": windows,
    }
