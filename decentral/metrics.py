"""Scores of a relative-pose estimate against ground truth, as Liu et al. 2024 Table I defines them.

For every step and every assembly A other than the reference assembly O, the true relative pose is
the pose of A's root horizontal frame in O's at the same time,

.. math::

    p^{O}_{A} = R_O^{T} (p_A - p_O), \\qquad \\theta^{O}_{A} = \\mathrm{yaw}(R_O^{T} R_A),

(Liu et al. 2024 eq. (19) applied to the true world poses). Over the steps where the estimate places A:

- positional error [m]: mean of :math:`\\lVert \\hat p - p \\rVert`;
- relative positional error [%]: mean of :math:`100 \\lVert \\hat p - p \\rVert / \\lVert p \\rVert`, the error
  divided by the current observer-target distance (Liu et al. 2024 §V-D);
- angular error [deg]: mean of :math:`|\\mathrm{wrap}(\\hat\\theta - \\theta)|`;
- coverage: fraction of the truth steps at which A is placed.

"Overall" pools every placed (step, assembly) pair. A mean over no pairs is ``None``, never NaN.
Estimate steps are matched to truth steps by time.

References
----------
.. [1] Y. Liu et al., "Configuration-Adaptive Visual Relative Localization for Spherical Modular
   Self-Reconfigurable Robots" (Liu et al. 2024), §V-D, Table I.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from decentral.errors import InputError
from decentral.geometry import yaw_of
from decentral.observations import Estimate, require_estimate

__all__ = ["GroundTruth", "AssemblyScore", "Score", "relative_truth", "score_estimate", "estimate_gap"]


@dataclass(frozen=True)
class GroundTruth:
    """True world poses of every assembly root at every step.

    Attributes
    ----------
    times : ndarray, shape (T,)
        Step times [s], strictly increasing.
    R : dict[str, ndarray of shape (T, 3, 3)]
        Per assembly, R_{H_r}^W at each step (yaw-only rotations).
    p : dict[str, ndarray of shape (T, 3)]
        Per assembly, p_{H_r}^W at each step [m].
    """

    times: np.ndarray
    R: dict
    p: dict

    def __post_init__(self):
        times = np.asarray(self.times, dtype=float)
        if times.ndim != 1 or (len(times) > 1 and np.any(np.diff(times) <= 0)):
            raise InputError("truth times must be a strictly increasing 1-D array", field="times")
        if set(self.R) != set(self.p):
            raise InputError("rotations and positions name different assemblies", field="poses")
        for name in self.R:
            if np.shape(self.R[name]) != (len(times), 3, 3) or np.shape(self.p[name]) != (len(times), 3):
                raise InputError(f"pose arrays of {name!r} do not match the {len(times)} steps", field="poses")
        object.__setattr__(self, "times", times)


@dataclass(frozen=True)
class AssemblyScore:
    """Scores of one assembly (or of all pooled).

    ``position_m``, ``relative_position_pct`` and ``yaw_deg`` are means over placed steps, ``None``
    when nothing was placed; ``placed`` of ``total`` truth steps were placed.
    """

    position_m: float | None
    relative_position_pct: float | None
    yaw_deg: float | None
    placed: int
    total: int

    @property
    def coverage(self) -> float:
        """Fraction of truth steps placed (0 when there are none)."""
        return self.placed / self.total if self.total else 0.0

    def to_dict(self) -> dict:
        """Plain-JSON form."""
        return {
            "position_m": self.position_m,
            "relative_position_pct": self.relative_position_pct,
            "yaw_deg": self.yaw_deg,
            "coverage": self.coverage,
            "placed": self.placed,
            "total": self.total,
        }


@dataclass(frozen=True)
class Score:
    """Per-assembly and pooled scores of one estimate against one truth."""

    reference: str
    per_assembly: dict
    overall: AssemblyScore
    unmatched_steps: int

    def to_dict(self) -> dict:
        """Plain-JSON form."""
        return {
            "reference": self.reference,
            "overall": self.overall.to_dict(),
            "assemblies": {name: s.to_dict() for name, s in self.per_assembly.items()},
            "unmatched_steps": self.unmatched_steps,
        }


def relative_truth(truth: GroundTruth, reference: str, target: str) -> tuple[np.ndarray, np.ndarray]:
    """True pose of ``target``'s root in ``reference``'s root frame at every step.

    Returns
    -------
    p : ndarray, shape (T, 3)
        p_{H_target}^{H_reference} [m].
    theta : ndarray, shape (T,)
        Yaw of R_{H_target}^{H_reference} [rad], in (-pi, pi].
    """
    R0, p0 = truth.R[reference], truth.p[reference]
    # Liu et al. 2024 eq. (19) on true poses: R_1^0 = R_0^T R_1, p_1^0 = R_0^T (p_1 - p_0)
    p = np.einsum("tji,tj->ti", R0, truth.p[target] - p0)
    R = np.einsum("tji,tjk->tik", R0, truth.R[target])
    return p, yaw_of(R)


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def score_estimate(truth: GroundTruth, estimate: Estimate, *, time_tol: float = 1e-6) -> Score:
    """Score ``estimate`` against ``truth`` (Liu et al. 2024 Table I metrics, see the module docstring).

    Parameters
    ----------
    truth : GroundTruth
        Must name the estimate's reference and every assembly the estimate places.
    estimate : Estimate
        Poses relative to ``estimate.reference``'s root frame.
    time_tol : float
        An estimate step matches the truth step whose time is within ``time_tol`` seconds.

    Returns
    -------
    Score
        One :class:`AssemblyScore` per truth assembly other than the reference, and the pooled one.
        Estimate steps with no matching truth time are counted in ``unmatched_steps``.
    """
    estimate = require_estimate(estimate)
    if not isinstance(truth, GroundTruth):
        raise InputError(f"expected a GroundTruth, got {type(truth).__name__}", field="truth")
    ref = estimate.reference
    if ref not in truth.R:
        raise InputError(f"reference {ref!r} is not in the truth", field="reference")
    targets = [name for name in truth.R if name != ref]
    rel = {name: relative_truth(truth, ref, name) for name in targets}
    errors = {name: ([], [], []) for name in targets}
    placed_at: dict[str, set[int]] = {name: set() for name in targets}
    unmatched = 0
    times = truth.times
    for step in estimate.steps:
        k = int(np.searchsorted(times, step.t))
        cands = [j for j in (k - 1, k) if 0 <= j < len(times) and abs(times[j] - step.t) <= time_tol]
        if not cands:
            unmatched += 1
            continue
        k = min(cands, key=lambda j: abs(times[j] - step.t))
        for name, pose in step.poses.items():
            if name not in rel:
                if name == ref:
                    continue
                raise InputError(f"estimate places {name!r}, which is not in the truth", field="steps.poses")
            if k in placed_at[name]:
                continue
            placed_at[name].add(k)
            p_true, th_true = rel[name][0][k], rel[name][1][k]
            err = float(np.linalg.norm(np.asarray(pose.p, dtype=float) - p_true))
            dist = float(np.linalg.norm(p_true))
            dyaw = float(np.angle(np.exp(1j * (float(pose.theta) - th_true))))
            errors[name][0].append(err)
            if dist > 0:  # coincident roots cannot happen physically; never divide by zero
                errors[name][1].append(100.0 * err / dist)
            errors[name][2].append(abs(np.degrees(dyaw)))
    per = {}
    pooled = ([], [], [])
    for name in targets:
        e = errors[name]
        per[name] = AssemblyScore(_mean(e[0]), _mean(e[1]), _mean(e[2]), len(placed_at[name]), len(times))
        for dst, src in zip(pooled, e):
            dst.extend(src)
    overall = AssemblyScore(
        _mean(pooled[0]),
        _mean(pooled[1]),
        _mean(pooled[2]),
        sum(len(s) for s in placed_at.values()),
        len(times) * len(targets),
    )
    return Score(ref, per, overall, unmatched)


def estimate_gap(a: Estimate, b: Estimate) -> tuple[float, float, int]:
    """How far two estimates of the same log are apart (e.g. decentralized vs centralized).

    Steps are paired in order. Returns the largest position difference (m) and the largest yaw
    difference (rad, wrapped) over the assemblies both place, and the number of (step, assembly)
    placements only one of them makes.
    """
    a, b = require_estimate(a), require_estimate(b)
    dp = dth = 0.0
    mismatched = 0
    for sa, sb in zip(a.steps, b.steps):
        mismatched += len(set(sa.poses) ^ set(sb.poses))
        for name in set(sa.poses) & set(sb.poses):
            pa, pb = sa.poses[name], sb.poses[name]
            dp = max(dp, float(np.linalg.norm(pa.p - pb.p)))
            dth = max(dth, abs(float(np.angle(np.exp(1j * (pa.theta - pb.theta))))))
    return dp, dth, mismatched
