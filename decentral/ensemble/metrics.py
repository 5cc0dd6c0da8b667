"""Accuracy of an ensemble estimate against ground truth, as in Funiak et al. 2008 §VI-C and Fig. 10.

The model (eq. 1) does not forbid overlap, so an estimate is first scaled uniformly until its mean
spacing between observed neighbours equals the true mean spacing; it is then rigidly aligned to the
truth (eq. 5, closed form) and the RMS position error is reported in module radii (global RMS).
The local RMS partitions the ensemble greedily into connected regions of diameter at most six
module diameters and aligns each region on its own, so it measures the error of modules relative to
their neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from decentral.ensemble.alignment import AlignmentStats
from decentral.errors import InputError

__all__ = ["EnsembleErrors", "scale_to_spacing", "aligned", "local_regions", "evaluate"]


@dataclass(frozen=True)
class EnsembleErrors:
    """Accuracy figures of one estimate (all lengths in module radii).

    Attributes
    ----------
    global_rms : float
        RMS centre error after scaling to the true spacing and one rigid alignment of the whole.
    local_rms : float
        RMS centre error after a rigid alignment of each region of diameter <= ``region_diameter``
        module diameters (Funiak et al. 2008 Fig. 10b).
    scale : float
        Factor applied to the estimate to match the true mean neighbour spacing.
    regions : int
        Number of regions of the local RMS.
    """

    global_rms: float
    local_rms: float
    scale: float
    regions: int


def scale_to_spacing(estimate: np.ndarray, truth: np.ndarray, pairs: np.ndarray) -> float:
    """Factor s such that s * estimate has the true mean distance over neighbour ``pairs`` (P, 2)."""
    est = np.linalg.norm(estimate[pairs[:, 0]] - estimate[pairs[:, 1]], axis=1).mean()
    tru = np.linalg.norm(truth[pairs[:, 0]] - truth[pairs[:, 1]], axis=1).mean()
    return float(tru / est) if est > 0 else 1.0


def aligned(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``estimate`` (m, d) moved by the rigid transform that best fits it to ``truth`` (m, d)."""
    return AlignmentStats.from_points(truth, estimate).solve().apply(estimate)


def local_regions(truth: np.ndarray, adjacency: sparse.spmatrix, radius: float, diameter: float = 6.0) -> np.ndarray:
    """Greedy partition into connected regions of true diameter <= ``diameter`` module diameters.

    Modules are visited in id order; an unassigned module seeds a region made of the unassigned
    modules within ``diameter`` module radii (half the region diameter) of it in the true layout
    that are connected to it through such modules. Returns the region label (n,) of each module.
    """
    n = truth.shape[0]
    A = sparse.csr_matrix(adjacency)
    tree = cKDTree(truth)
    label = np.full(n, -1, dtype=np.int64)
    reach = diameter * radius  # half of `diameter` module diameters
    k = 0
    from scipy.sparse.csgraph import breadth_first_order

    for seed in range(n):
        if label[seed] >= 0:
            continue
        ball = np.array(tree.query_ball_point(truth[seed], reach * (1 + 1e-9)), dtype=np.int64)
        ball = ball[label[ball] < 0]
        sub = A[ball][:, ball]
        s = int(np.flatnonzero(ball == seed)[0])
        members = breadth_first_order(sub, s, directed=False, return_predecessors=False)
        label[ball[members]] = k
        k += 1
    return label


def evaluate(estimate: np.ndarray, truth: np.ndarray, pairs: np.ndarray, radius: float,
             region_diameter: float = 6.0) -> EnsembleErrors:
    """Global and local RMS errors (module radii) of centres ``estimate`` (n, d) vs ``truth`` (n, d).

    ``pairs`` (P, 2) are the observed neighbour pairs (spacing and region connectivity).
    """
    estimate = np.asarray(estimate, float)
    truth = np.asarray(truth, float)
    if estimate.shape != truth.shape:
        raise InputError(f"shape {estimate.shape} does not match truth {truth.shape}", field="position")
    n = truth.shape[0]
    s = scale_to_spacing(estimate, truth, pairs)
    est = estimate * s
    glob = np.sqrt(np.mean(np.sum((aligned(est, truth) - truth) ** 2, axis=1))) / radius
    A = sparse.csr_matrix((np.ones(2 * len(pairs)), (np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]])),
                          shape=(n, n))
    region = local_regions(truth, A, radius, region_diameter)
    order = np.argsort(region, kind="stable")
    bounds = np.searchsorted(region[order], np.arange(region.max() + 2))
    sq = 0.0
    for r in range(region.max() + 1):
        m = order[bounds[r]:bounds[r + 1]]
        if m.size > 1:
            sq += float(np.sum((aligned(est[m], truth[m]) - truth[m]) ** 2))
    loc = np.sqrt(sq / n) / radius
    return EnsembleErrors(float(glob), float(loc), s, int(region.max() + 1))
