"""Funiak et al. 2008 Algorithm 1 (NormCutLocalize): recursive normalized cut, closed-form merges, refinement.

The contact graph is split in two by normalized cut (eq. 4), each side is localized recursively,
the two partial solutions are joined by the optimal rigid transform between the observations that
cross the cut (eq. 5), and the union is refined to the maximum likelihood (eq. 3). Above a size
threshold the cut is computed on an abstraction of the graph (random leaders, hop-count clusters;
§IV-C). A side of a cut that is not connected is handled as several parts, merged one at a time in
order of the number of observations linking them to what is already merged.

Subproblems are extracted from their parent's, never from the whole problem, so the work per level
is linear in the observations and the total is O(E log n) plus the refinements. Below the top, a
merge refines by default only its seam (the modules near the crossing observations, inside a held
ring), so the refinement work per level follows the seams, not the level's size.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from scipy.sparse.csgraph import connected_components

from decentral.ensemble.abstraction import abstract_graph, choose_leaders, hop_clusters
from decentral.ensemble.alignment import AlignmentStats, merge_point_pairs
from decentral.ensemble.ncut import normalized_cut
from decentral.ensemble.ordering import hierarchy_order
from decentral.ensemble.breadth_first import place_breadth_first
from decentral.ensemble.problem import EnsembleEstimate, EnsembleProblem
from decentral.ensemble.refine import RefineConfig, refine

__all__ = [
    "HierarchyConfig",
    "HierarchyNode",
    "LocalizationResult",
    "SeamBand",
    "seam_band",
    "normcut_localize",
    "split",
    "merge_parts",
    "layout_components",
    "localize_components",
]


#: refiners whose levels may be refined on the seam only (see ``HierarchyConfig.seam_hops``)
SEAM_METHODS = ("lbfgs", "alternating")


@dataclass(frozen=True)
class HierarchyConfig:
    """Parameters of Algorithm 1.

    Attributes
    ----------
    leaf_size : int
        A set of at most this many modules is "sufficiently small" (line 1): it is placed breadth
        first and refined directly.
    cut : str
        ``"abstract"``: cut an abstraction of the graph with ``abstract_size`` random leaders
        whenever the set is larger than ``4 * abstract_size`` (Funiak et al. 2008 §IV-C); ``"exact"``: always
        cut the contact graph itself.
    abstract_size : int
        Number of leaders (abstract nodes) per abstraction (Funiak et al. 2008 Fig. 7: 20 or more suffice).
    level_refine : RefineConfig
        Refinement of each leaf and after each merge below the top (Algorithm 1 lines 2 and 11).
        Default: L-BFGS on the centres (:func:`~decentral.ensemble.refine.refine`, ``"lbfgs"``)
        to a largest gradient entry of 1e-3 radii.
    final_refine : RefineConfig
        Refinement of the whole ensemble (the top merge): L-BFGS to 1e-6 radii, or until 20
        steps together lower the cost by less than 1e-10 of it, at most 300 iterations. (3D
        ensembles have a soft twisting mode along which the cost creeps down by ~1e-12 per step
        for hundreds of steps; a per-step test stopped triple3d's top at 179-392 iterations
        depending on rounding in the levels below, the 20-step window at 184-220, about as close
        to the optimum.) Its initial inverse Hessian adds the rigid motions of clusters of about 500
        modules to 4 L^-1 (``coarse_size``, :mod:`decentral.ensemble.coarse`), which relaxes that
        twisting mode directly.
    seam_hops : int
        Below the top, refine only the seam of each merge: the modules within this many hops of an
        observation that crosses the cut, inside a ring of their neighbours held fixed (both parts
        were refined at their own level; the likelihood changed only through the crossing
        observations). ``0`` refines every module of the level, as the seed does. Applies to the
        ``"lbfgs"`` and ``"alternating"`` refiners, whose Laplacian solves at the top carry any
        correction left in the interiors across the whole ensemble in one step; ``"pcg"`` and
        ``"lm"`` levels are always refined in full (the paper's protocol: PCG moves information one
        contact per iteration).
    seam_fraction : float
        Seam-only refinement applies to merges of at most this fraction of the component's modules;
        the larger merges (the top's children and grandchildren for balanced cuts) are refined in
        full, so the long-wavelength modes are already relaxed when the top starts. Measured on
        ``triple`` (25,000 -> 100,000 modules) and ``triple3d`` (5,000 -> 20,000): with seams at
        every level the top needed 75 -> 100 and 269 -> 300 (capped) iterations, with 0.25 it
        needed 63 -> 64 and 217 -> 187.
    """

    leaf_size: int = 64
    cut: str = "abstract"
    abstract_size: int = 64
    level_refine: RefineConfig = RefineConfig(max_iter=100, gtol=1e-3, method="lbfgs", history=30)
    final_refine: RefineConfig = RefineConfig(max_iter=300, gtol=1e-6, ftol=1e-10, ftol_window=20,
                                              method="lbfgs", history=30, coarse_size=500)
    seam_hops: int = 2
    seam_fraction: float = 0.25

    def with_tolerance(self, gtol: float) -> "HierarchyConfig":
        """This configuration with every refinement (each level's and the top's) stopping at a largest
        gradient entry of ``gtol`` module radii (Funiak et al. 2008 §VI-B: "a fixed level of accuracy")."""
        if not (np.isfinite(gtol) and gtol > 0):
            raise ValueError(f"gtol must be a positive number, got {gtol!r}")
        return replace(self, level_refine=replace(self.level_refine, gtol=gtol),
                       final_refine=replace(self.final_refine, gtol=gtol))


@dataclass(frozen=True)
class HierarchyNode:
    """One call of Algorithm 1: its modules (global ids), its parts and the cut that made them."""

    nodes: np.ndarray
    level: int
    children: tuple[int, ...] = ()
    ncut: float = float("nan")
    refine_iterations: int = 0
    refine_status: str = ""


@dataclass(frozen=True)
class LocalizationResult:
    """Result of an ensemble localizer.

    Attributes
    ----------
    estimate : EnsembleEstimate
    cost : float
        Negative log-likelihood at the estimate (metres^2), summed over components.
    iterations_per_module : ndarray, shape (n,)
        Refinement iterations charged to each module: the sum over all refinements that included it
        (Funiak et al. 2008 Fig. 6 plots its mean).
    status : str
        ``"ok"``, or a short reason when a refinement did not converge (the estimate is still the
        best found, never NaN).
    hierarchy : tuple of HierarchyNode
        The calls of Algorithm 1 in completion order (children before parents); empty for
        baselines.
    info : dict
        Free-form numbers (depth, counts, timings).
    """

    estimate: EnsembleEstimate
    cost: float
    iterations_per_module: np.ndarray
    status: str
    hierarchy: tuple = ()
    info: dict = field(default_factory=dict)


def split(sub: EnsembleProblem, config: HierarchyConfig, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Line 4 of Algorithm 1: a normalized-cut partition of a connected subproblem.

    Returns ``in_a`` (bool, n) and the Ncut value (of the graph that was cut: the abstraction when
    one was used).
    """
    adj = sub.adjacency()
    if config.cut == "abstract" and sub.n > 4 * config.abstract_size:
        leaders = choose_leaders(sub.n, config.abstract_size, rng)
        cl = hop_clusters(adj, leaders)
        W = abstract_graph(adj, cl.cluster, leaders.size)
        res = normalized_cut(W)
        return res.in_a[cl.cluster], res.value
    if config.cut not in ("abstract", "exact"):
        raise ValueError(f"unknown cut {config.cut!r}")
    res = normalized_cut(adj)
    return res.in_a, res.value


def merge_parts(sub: EnsembleProblem, part: np.ndarray, poses: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Lines 7-10 of Algorithm 1: join partial solutions by closed-form rigid alignment.

    Parameters
    ----------
    sub : EnsembleProblem
        The (connected) subproblem.
    part : ndarray of int, shape (n,)
        Part index of each module, ``0..P-1``.
    poses : list of (position (n_p, d), rotation (n_p, d, d))
        Each part's estimate in its own frame, rows in increasing module order within the part.

    Returns
    -------
    position, rotation : the union in the frame of the largest part.
    """
    n, d = sub.n, sub.dim
    P = len(poses)
    pos = np.zeros((n, d))
    rot = np.tile(np.eye(d), (n, 1, 1))
    members = [np.flatnonzero(part == p) for p in range(P)]
    for p in range(P):
        pos[members[p]], rot[members[p]] = poses[p]
    sizes = np.array([m.size for m in members])
    merged = np.zeros(P, dtype=bool)
    merged[int(np.argmax(sizes))] = True
    i, j, z = sub.i, sub.j, sub.z
    rev = _reverse(sub)
    pi, pj = part[i], part[j]
    while not merged.all():
        cross = merged[pi] & ~merged[pj]
        links = np.bincount(pj[cross], minlength=P)
        links[merged] = -1
        p = int(np.argmax(links))
        e = np.flatnonzero(cross & (pj == p))
        # Funiak et al. 2008 eq. (5): align part p (frame q) onto the merged set (frame p) from the crossing pairs
        a, b = i[e], j[e]
        pts_p, pts_q = merge_point_pairs(pos[a], rot[a], pos[b], rot[b], z[e], z[rev[e]])
        T = AlignmentStats.from_points(pts_p, pts_q).solve()
        m = members[p]
        pos[m], rot[m] = T.apply_pose(pos[m], rot[m])
        merged[p] = True
    return pos, rot


@dataclass(frozen=True)
class SeamBand:
    """Modules refined after a merge (``free``) and the ring around them held fixed (``ring``), bool (n,)."""

    free: np.ndarray
    ring: np.ndarray


def seam_band(sub: EnsembleProblem, part: np.ndarray, hops: int) -> SeamBand | None:
    """The modules within ``hops`` hops of an observation crossing between parts, and their outer ring.

    Parameters
    ----------
    sub : EnsembleProblem
    part : ndarray of int, shape (n,)
        Part index of each module.
    hops : int
        Breadth of the band (0 = the crossing modules themselves).

    Returns
    -------
    SeamBand, or None when the band and its ring cover every module (then the whole set is
    refined, which is the same problem).
    """
    adj = sub.adjacency()
    free = np.zeros(sub.n, dtype=bool)
    cross = part[sub.i] != part[sub.j]
    free[sub.i[cross]] = True
    free[sub.j[cross]] = True
    for _ in range(hops):  # breadth-first growth, one sparse product per hop
        free |= (adj @ free.astype(np.float64)) > 0
    ring = ((adj @ free.astype(np.float64)) > 0) & ~free
    if (free | ring).all():
        return None
    return SeamBand(free, ring)


def _reverse(sub: EnsembleProblem) -> np.ndarray:
    n = sub.n
    key = sub.i * n + sub.j
    order = np.argsort(key)
    return order[np.searchsorted(key[order], sub.j * n + sub.i)]


class _Run:
    def __init__(self, problem, config, rng, progress=None):
        self.problem, self.config, self.rng, self.progress = problem, config, rng, progress
        self.placed = 0  # modules placed by a leaf so far (the progress count)
        self.root_n = problem.n  # modules of the component being solved (set by its top call)
        self.iters = np.zeros(problem.n)
        self.tree: list[HierarchyNode] = []
        self.bad: list[str] = []
        self.max_level = 0

    def solve(self, sub: EnsembleProblem, nodes: np.ndarray, level: int,
              top: bool) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
        """Algorithm 1 on ``sub`` (whose modules are ``nodes`` globally): centres (n, d), rotations
        (n, d, d), the index of its node in ``self.tree``, and the cuts below it as an elimination
        order of its modules (:func:`~decentral.ensemble.ordering.hierarchy_order`)."""
        cfg = self.config
        if top:
            self.root_n = sub.n
        self.max_level = max(self.max_level, level)
        rcfg = cfg.final_refine if top else cfg.level_refine
        if sub.n <= cfg.leaf_size:
            # line 2: local heuristic for a small set
            pos, rot, _ = place_breadth_first(sub)
            res = refine(sub, pos, rot, rcfg)
            self.iters[nodes] += res.iterations
            self.tree.append(HierarchyNode(nodes, level, (), float("nan"), res.iterations, res.status))
            if res.status == "stalled":
                self.bad.append(f"leaf of {sub.n} modules: {res.status}")
            self.placed += sub.n
            if self.progress is not None:
                self.progress(self.placed, self.problem.n, stage="leaves", depth=level)
            return res.position, res.rotation, len(self.tree) - 1, np.arange(sub.n)
        in_a, value = split(sub, cfg, self.rng)
        # lines 5-6: each connected piece of A and of B is localized on its own
        side = in_a.astype(np.int64)
        keep = side[sub.i] == side[sub.j]
        import scipy.sparse as sp

        g = sp.csr_matrix((np.ones(int(keep.sum())), (sub.i[keep], sub.j[keep])), shape=(sub.n, sub.n))
        _, comp = connected_components(g, directed=False)
        _, part = np.unique(comp, return_inverse=True)
        P = int(part.max()) + 1
        if P == 1:  # degenerate cut (cannot happen for a connected graph with n >= 2); split in order
            part = (np.arange(sub.n) >= sub.n // 2).astype(np.int64)
            P = 2
        poses, kids, orders = [], [], []
        for p in range(P):
            loc = np.flatnonzero(part == p)
            child = sub.subproblem(loc)
            cpos, crot, cid, corder = self.solve(child, nodes[loc], level + 1, False)
            poses.append((cpos, crot))
            kids.append(cid)
            orders.append(loc[corder])
        pos, rot = merge_parts(sub, part, poses)
        order = hierarchy_order(sub.i, sub.j, part, orders)
        # line 11: refine the union starting from the aligned parts
        if top and self.progress is not None:
            self.progress(self.placed, self.problem.n, stage="top refinement", depth=self.max_level)
        band = None
        if (not top and cfg.seam_hops > 0 and rcfg.method in SEAM_METHODS
                and sub.n <= cfg.seam_fraction * self.root_n):
            band = seam_band(sub, part, cfg.seam_hops)
        if band is None:
            res = refine(sub, pos, rot, rcfg, elimination=order)
            pos, rot = res.position, res.rotation
            self.iters[nodes] += res.iterations
        else:
            # only the seam moved out of its parts' optima: refine it inside a held ring
            local = np.flatnonzero(band.free | band.ring)
            res = refine(sub.subproblem(local), pos[local], rot[local], rcfg, fixed=band.ring[local])
            pos[local], rot[local] = res.position, res.rotation
            self.iters[nodes[band.free]] += res.iterations
        if res.status == "stalled":
            self.bad.append(f"merge of {sub.n} modules: {res.status}")
        self.tree.append(HierarchyNode(nodes, level, tuple(kids), value, res.iterations, res.status))
        return pos, rot, len(self.tree) - 1, order


def layout_components(positions: list[np.ndarray], radius: float) -> list[np.ndarray]:
    """Translate per-component estimates side by side along x (gap of 4 radii) so none overlap."""
    out, x0 = [], 0.0
    for p in positions:
        lo, hi = p.min(axis=0), p.max(axis=0)
        shift = np.zeros(p.shape[1])
        shift[0] = x0 - lo[0] + radius
        shift[1:] = -0.5 * (lo[1:] + hi[1:])
        out.append(p + shift)
        x0 += (hi[0] - lo[0]) + 4.0 * radius
    return out


def localize_components(problem: EnsembleProblem, solve_component) -> tuple[EnsembleEstimate, float, list]:
    """Run ``solve_component(sub, nodes) -> (position, rotation, cost)`` per connected component and lay
    the results side by side. Returns the estimate, the summed cost and the per-component outputs.

    Components are taken largest first (ties: smallest module id). A module with no observation at
    all is a component of its own with nothing to solve: it keeps the identity orientation and its
    slot in the layout, without a call (a file of 10**6 unobserved modules is laid out at once).
    Every component's subproblem is cut from one pass over the observations, so many small
    components cost time linear in the problem size.
    """
    n, d = problem.n, problem.dim
    k, labels = connected_components(problem.adjacency(), directed=False)
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(k + 1))
    sizes = np.diff(bounds)
    rank = np.lexsort((order[bounds[:-1]], -sizes))  # component ids, largest first
    new_label = np.empty(k, dtype=np.int64)
    new_label[rank] = np.arange(k)
    local = np.empty(n, dtype=np.int64)  # each module's index inside its component (ascending ids)
    local[order] = np.arange(n) - bounds[labels[order]]
    edge_order = np.argsort(labels[problem.i], kind="stable")
    edge_bounds = np.searchsorted(labels[problem.i][edge_order], np.arange(k + 1))
    pos = np.zeros((n, d))
    rot = np.tile(np.eye(d), (n, 1, 1))
    parts, comps, cost = [], [], 0.0
    for c in rank[sizes[rank] > 1]:
        nodes = order[bounds[c]:bounds[c + 1]]
        if k == 1:
            sub = problem
        else:
            e = edge_order[edge_bounds[c]:edge_bounds[c + 1]]
            sub = EnsembleProblem(d, int(nodes.size), problem.radius, local[problem.i[e]], local[problem.j[e]],
                                  problem.z[e])
        p, r, cst = solve_component(sub, nodes)
        parts.append(p)
        comps.append(nodes)
        rot[nodes] = r
        cost += cst
    if k > 1:
        parts = layout_components(parts, problem.radius)
    for nodes, p in zip(comps, parts):
        pos[nodes] = p
    singles = order[bounds[rank[sizes[rank] == 1]]]
    if singles.size:  # after the others, 4 radii apart, as layout_components would place them
        x0 = sum(float(np.ptp(p[:, 0])) + 4.0 * problem.radius for p in parts)
        pos[singles, 0] = x0 + problem.radius + 4.0 * problem.radius * np.arange(singles.size)
    return EnsembleEstimate(pos, rot, new_label[labels]), cost, []


def normcut_localize(problem: EnsembleProblem, rng: np.random.Generator,
                     config: HierarchyConfig = HierarchyConfig(),
                     progress: Callable[..., None] | None = None) -> LocalizationResult:
    """Localize every module by Funiak et al.'s Algorithm 1 (NormCutLocalize).

    Parameters
    ----------
    problem : EnsembleProblem
    rng : numpy.random.Generator
        Draws the leaders of each graph abstraction (unused with ``config.cut == "exact"``).
    config : HierarchyConfig
    progress : callable, optional
        Called as ``progress(modules_placed, n, stage=..., depth=...)`` after each leaf (line 2) and
        when a component's top refinement starts; the library never prints.

    Returns
    -------
    LocalizationResult
        Positions (n, d) and orientations in one arbitrary global frame; each connected component
        of the contact graph is solved on its own and the components are laid side by side.

    Examples
    --------
    Sixteen touching modules of radius 5 cm on a 4 x 4 grid, randomly turned; each observes the
    contact point of each neighbour on its own perimeter, in its own frame (``z_ij = R_i^T (c_j - c_i) / 2``):

    >>> from decentral.ensemble import EnsembleProblem
    >>> from decentral.ensemble.rotation import angle_to_matrix
    >>> rng = np.random.default_rng(0)
    >>> r = 0.05
    >>> centre = np.array([[2 * r * x, 2 * r * y] for x in range(4) for y in range(4)])
    >>> R = angle_to_matrix(rng.uniform(-np.pi, np.pi, len(centre)))
    >>> i, j = np.nonzero(np.isclose(np.linalg.norm(centre[:, None] - centre[None], axis=2), 2 * r))
    >>> z = np.einsum("eba,eb->ea", R[i], (centre[j] - centre[i]) / 2)
    >>> problem = EnsembleProblem.create(2, len(centre), r, i, j, z)
    >>> est = normcut_localize(problem, rng).estimate
    >>> distances = lambda x: np.linalg.norm(x[:, None] - x[None], axis=2)
    >>> bool(np.abs(distances(est.position) - distances(centre)).max() < 1e-6)
    True
    """
    run = _Run(problem, config, rng, progress)
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10_000))
    try:
        def solve_component(sub, nodes):
            p, r, _, _ = run.solve(sub, nodes, 0, True)
            return p, r, 0.0

        est, _, _ = localize_components(problem, solve_component)
    finally:
        sys.setrecursionlimit(limit)
    from decentral.ensemble.model import residuals_from_matrices

    r = residuals_from_matrices(problem, est.position, est.rotation)
    cost = 0.5 * float(np.einsum("ea,ea->", r, r))
    status = "ok" if not run.bad else "; ".join(run.bad[:3])
    info = {"depth": run.max_level, "calls": len(run.tree)}
    return LocalizationResult(est, cost, run.iters, status, tuple(run.tree), info)
