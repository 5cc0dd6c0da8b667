"""Tests of the sparse spectral normalized cut (Funiak et al. 2008 eq. 4)."""

import numpy as np
from scipy import sparse

from decentral.ensemble import ncut as ncut_mod
from decentral.ensemble.ncut import fiedler_vector, ncut_value, normalized_cut


def _grid(nx, ny, offset=0):
    idx = np.arange(nx * ny).reshape(nx, ny) + offset
    e = [(idx[a, b], idx[a + 1, b]) for a in range(nx - 1) for b in range(ny)]
    e += [(idx[a, b], idx[a, b + 1]) for a in range(nx) for b in range(ny - 1)]
    return e


def _two_rooms(k=12, bridges=2):
    """Two dense k x k grids joined by ``bridges`` edges (Funiak et al. 2008 Fig. 3a)."""
    e = _grid(k, k) + _grid(k, k, k * k)
    for b in range(bridges):
        e.append(((k - 1) * k + b * (k // bridges), k * k + b * (k // bridges)))
    e = np.array(e)
    n = 2 * k * k
    W = sparse.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    return W, n


def test_cut_separates_weakly_joined_rooms():
    """The cut of two dense rooms joined by two observations is exactly the two rooms."""
    W, n = _two_rooms()
    res = normalized_cut(W)
    side = res.in_a
    assert len(set(side[: n // 2])) == 1 and len(set(side[n // 2:])) == 1 and side[0] != side[-1]


def test_reported_value_is_exact_ncut():
    """The value returned is eq. (4) evaluated on the returned partition."""
    W, _ = _two_rooms(bridges=3)
    res = normalized_cut(W)
    assert np.isclose(res.value, ncut_value(W, res.in_a))


def test_sparse_and_dense_eigensolvers_agree(monkeypatch):
    """The shift-invert sparse path and the dense path give the same Fiedler vector (up to sign)."""
    W, _ = _two_rooms(k=15)
    dense = fiedler_vector(W)
    monkeypatch.setattr(ncut_mod, "DENSE_BELOW", 10)
    sparse_y = fiedler_vector(W)
    assert min(np.abs(dense - sparse_y).max(), np.abs(dense + sparse_y).max()) < 1e-6 * np.abs(dense).max()


def test_self_loops_count_in_assoc_not_in_cut():
    """Self-loop weight (observations inside an abstract node) enters assoc(A, V) only."""
    W = sparse.csr_matrix(np.array([[4.0, 1.0], [1.0, 2.0]]))
    mask = np.array([True, False])
    assert np.isclose(ncut_value(W, mask), 1.0 / 5.0 + 1.0 / 3.0)


def test_cut_is_better_than_random_partitions():
    """No random balanced partition has a smaller Ncut than the spectral one on the rooms graph."""
    W, n = _two_rooms(k=10, bridges=4)
    best = normalized_cut(W).value
    rng = np.random.default_rng(0)
    for _ in range(50):
        mask = rng.random(n) < 0.5
        assert ncut_value(W, mask) >= best
