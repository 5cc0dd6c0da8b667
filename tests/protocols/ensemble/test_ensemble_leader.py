"""Tests of the group leader's reductions against the centralized routines."""

import numpy as np
from scipy import sparse

from decentral.ensemble import AlignmentStats, EnsembleProblem, RigidTransform, normalized_cut
from decentral.ensemble.hierarchical import merge_parts
from decentral.ensemble.alignment import merge_point_pairs
from decentral.ensemble.rotation import angle_to_matrix
from protocols.ensemble import cut_clusters, moved_target, plan_merge


def test_moved_target_matches_statistics_of_moved_points():
    """Moving the target side of the statistics equals recomputing them from moved points."""
    rng = np.random.default_rng(1)
    p, q = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.linalg.det(R)
    T = RigidTransform(R, rng.normal(size=3))
    a = moved_target(AlignmentStats.from_points(p, q), T).to_array()
    b = AlignmentStats.from_points(T.apply(p), q).to_array()
    assert np.allclose(a, b)


def _grid_problem(w, h):
    """Noiseless w x h lattice of touching 2D modules of radius 1 with random orientations."""
    rng = np.random.default_rng(3)
    xy = np.array([(x, y) for y in range(h) for x in range(w)], dtype=float) * 2.0
    th = rng.uniform(-np.pi, np.pi, len(xy))
    R = angle_to_matrix(th)
    ii, jj = [], []
    for a in range(len(xy)):
        for b in range(len(xy)):
            if a != b and np.isclose(np.linalg.norm(xy[a] - xy[b]), 2.0):
                ii.append(a)
                jj.append(b)
    ii, jj = np.array(ii), np.array(jj)
    z = np.einsum("mba,mb->ma", R[ii], 0.5 * (xy[jj] - xy[ii]))
    return EnsembleProblem.create(2, len(xy), 1.0, ii, jj, z), xy, R


def test_plan_merge_matches_centralized_merge_parts():
    """Transforms from aggregated per-pair statistics reproduce merge_parts on three parts."""
    prob, xy, R = _grid_problem(6, 3)
    part = np.repeat([0, 1, 2], 6)  # rows of the lattice
    rng = np.random.default_rng(5)
    poses, frames = [], []
    for p in range(3):
        m = np.flatnonzero(part == p)
        a = rng.uniform(-np.pi, np.pi)
        Rp = angle_to_matrix(np.array([a]))[0]
        t = rng.normal(size=2) * 5
        frames.append((Rp, t))
        poses.append((xy[m] @ Rp.T + t, np.einsum("ab,mbc->mac", Rp, R[m])))
    pos_c, rot_c = merge_parts(prob, part, poses)
    # distributed: statistics of each directed observation across the cut, keyed by (part_i, part_j)
    pos = np.concatenate([pp for pp, _ in poses])
    rot = np.concatenate([rr for _, rr in poses])
    key = prob.i * prob.n + prob.j
    rev = np.argsort(key)[np.searchsorted(np.sort(key), prob.j * prob.n + prob.i)]
    cross = part[prob.i] != part[prob.j]
    table = {}
    for e in np.flatnonzero(cross):
        a, b = prob.i[e], prob.j[e]
        pts_p, pts_q = merge_point_pairs(pos[a][None], rot[a][None], pos[b][None], rot[b][None], prob.z[e][None],
                                         prob.z[rev[e]][None])
        k = (part[a], part[b])
        s, c = table.get(k, (AlignmentStats.zero(2), 0))
        table[k] = (s + AlignmentStats.from_points(pts_p, pts_q), c + 1)
    pa = np.array([k[0] for k in table])
    pb = np.array([k[1] for k in table])
    T = plan_merge(np.array([0, 1, 2]), np.array([6, 6, 6]), pa, pb,
                   np.array([v[0].to_array() for v in table.values()]), np.array([v[1] for v in table.values()]))
    for p in range(3):
        m = np.flatnonzero(part == p)
        assert np.allclose(T[p].apply(poses[p][0]), pos_c[m], atol=1e-9)


def test_exact_cut_of_clusters_equals_cut_of_graph():
    """With one module per cluster, the leader's cut is the normalized cut of the contact graph."""
    prob, _, _ = _grid_problem(8, 3)
    adj = prob.adjacency()
    coo = sparse.coo_matrix(adj)
    plan = cut_clusters(coo.row, coo.col, coo.data.astype(int), np.arange(prob.n), np.ones(prob.n, int),
                        np.arange(prob.n))
    ref = normalized_cut(adj)
    assert np.isclose(plan.value, ref.value)
    side = plan.cluster_part == plan.cluster_part[0]
    assert np.array_equal(side, ref.in_a) or np.array_equal(side, ~ref.in_a)
    assert plan.part_size.sum() == prob.n and plan.part_leader[0] == 0
