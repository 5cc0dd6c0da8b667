"""Sparse operators on the observation graph of an ensemble: row-pattern matrices and the scaled incidence :class:`Incidence`."""

from __future__ import annotations

import numpy as np
from scipy import sparse

__all__ = ["Incidence", "row_matrix"]


def row_matrix(columns: np.ndarray, values: np.ndarray, n_cols: int) -> sparse.csr_matrix:
    """CSR matrix (E, n_cols) whose row e holds ``values[e]`` at ``columns[e]`` (both (E, k), k per row)."""
    rows, k = columns.shape
    return sparse.csr_matrix((values.ravel(), columns.ravel(), np.arange(0, rows * k + 1, k)),
                             shape=(rows, n_cols))


class Incidence:
    """The observation graph as sparse operators on centres (n, d) and per-observation arrays (E, d).

    ``half(c)`` = (c_j - c_i) / 2 per observation, B c with B the (E, n) incidence matrix scaled by
    1/2; ``gradient(r)`` = (sum_{e: i_e = k} r_e - sum_{e: j_e = k} r_e) / 2 per module, -B^T r: the
    position gradient of (1/2) sum_e |r_e|^2 with r_e = R_i z_e - (c_j - c_i) / 2. One sparse product
    each instead of one scatter per coordinate and end (3-5x faster on 5,000-20,000-module 3D ensembles).
    """

    def __init__(self, n: int, i: np.ndarray, j: np.ndarray):
        self.B = row_matrix(np.stack([i, j], 1), np.tile([-0.5, 0.5], (i.size, 1)), n)
        self.BT = self.B.T.tocsr()

    def half(self, c: np.ndarray) -> np.ndarray:
        return self.B @ c

    def gradient(self, r: np.ndarray) -> np.ndarray:
        g = self.BT @ r
        np.negative(g, out=g)
        return g
