"""Closed-form rigid alignment from first- and second-order statistics (Funiak et al. 2008 eq. 5, [1]_).

The optimal rigid transform between matched point sets depends on the points only through their
count, sums and sum of outer products (Umeyama [1]_). :class:`AlignmentStats` holds exactly these,
adds with ``+`` (so partial sums can be aggregated from the boundary of a cut towards a leader,
Funiak et al. 2008 §V-A) and has a fixed wire size that depends on the dimension only.

References
----------
.. [1] S. Umeyama, "Least-squares estimation of transformation parameters between two point
   patterns", IEEE TPAMI 13(4), 1991.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["AlignmentStats", "RigidTransform", "merge_point_pairs", "align_points"]


@dataclass(frozen=True)
class RigidTransform:
    """x -> R x + t.

    Attributes
    ----------
    R : ndarray, shape (d, d)
        Rotation (det +1).
    t : ndarray, shape (d,)
    residual : float
        sum_k |p_k - (R q_k + t)|^2 at the optimum (NaN-free; 0 for an empty set).
    """

    R: np.ndarray
    t: np.ndarray
    residual: float = 0.0

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Map points (m, d)."""
        return np.asarray(x, float) @ self.R.T + self.t

    def apply_pose(self, position: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map module poses: centres (m, d) and orientation matrices (m, d, d)."""
        return self.apply(position), np.einsum("ab,mbc->mac", self.R, rotation)


@dataclass(frozen=True)
class AlignmentStats:
    """Sufficient statistics of matched points {(p_k, q_k)} for the alignment p ~ R q + t.

    Attributes
    ----------
    count : float
        Number (or total weight) of pairs.
    sum_p, sum_q : ndarray, shape (d,)
    sum_pq : ndarray, shape (d, d)
        sum_k p_k q_k^T.
    sum_pp, sum_qq : float
        sum_k |p_k|^2 and sum_k |q_k|^2 (only for the residual).
    """

    count: float
    sum_p: np.ndarray
    sum_q: np.ndarray
    sum_pq: np.ndarray
    sum_pp: float
    sum_qq: float

    @classmethod
    def zero(cls, dim: int) -> "AlignmentStats":
        """Statistics of the empty set."""
        return cls(0.0, np.zeros(dim), np.zeros(dim), np.zeros((dim, dim)), 0.0, 0.0)

    @classmethod
    def from_points(cls, p: np.ndarray, q: np.ndarray, weights: np.ndarray | None = None) -> "AlignmentStats":
        """Statistics of pairs ``p`` (m, d) (target frame) and ``q`` (m, d) (source frame)."""
        p = np.asarray(p, float)
        q = np.asarray(q, float)
        w = np.ones(p.shape[0]) if weights is None else np.asarray(weights, float)
        return cls(float(w.sum()), w @ p, w @ q, (p * w[:, None]).T @ q,
                   float(w @ np.einsum("ma,ma->m", p, p)), float(w @ np.einsum("ma,ma->m", q, q)))

    def __add__(self, other: "AlignmentStats") -> "AlignmentStats":
        return AlignmentStats(self.count + other.count, self.sum_p + other.sum_p, self.sum_q + other.sum_q,
                              self.sum_pq + other.sum_pq, self.sum_pp + other.sum_pp, self.sum_qq + other.sum_qq)

    @property
    def dim(self) -> int:
        """Dimension d."""
        return int(self.sum_p.shape[0])

    def to_array(self) -> np.ndarray:
        """Flat float vector of length 3 + 2 d + d^2 (a message payload; inverse :meth:`from_array`)."""
        return np.concatenate([[self.count, self.sum_pp, self.sum_qq], self.sum_p, self.sum_q, self.sum_pq.ravel()])

    @classmethod
    def from_array(cls, a: np.ndarray) -> "AlignmentStats":
        """Inverse of :meth:`to_array`."""
        a = np.asarray(a, float)
        d = 2 if a.size == 3 + 4 + 4 else 3
        if a.size != 3 + 2 * d + d * d:
            raise ValueError(f"alignment statistics must have 11 (2D) or 18 (3D) values, got {a.size}")
        return cls(float(a[0]), a[3:3 + d].copy(), a[3 + d:3 + 2 * d].copy(),
                   a[3 + 2 * d:].reshape(d, d).copy(), float(a[1]), float(a[2]))

    def solve(self) -> RigidTransform:
        """The optimal rigid transform (Funiak et al. 2008 eq. 5) in closed form.

        .. math:: \\min_{R \\in SO(d), t} \\sum_k \\lVert p_k - (R q_k + t) \\rVert^2

        solved by the SVD of the cross-covariance (Umeyama). With no pairs the identity is returned;
        with fewer pairs than needed to fix the rotation the SVD picks one of the optimal rotations.
        """
        d = self.dim
        if self.count <= 0:
            return RigidTransform(np.eye(d), np.zeros(d), 0.0)
        mp = self.sum_p / self.count
        mq = self.sum_q / self.count
        # Funiak et al. 2008 eq. (5) via Umeyama: cross-covariance from first/second-order statistics only
        S = self.sum_pq - self.count * np.outer(mp, mq)
        U, sv, Vt = np.linalg.svd(S)
        D = np.ones(d)
        D[-1] = 1.0 if np.linalg.det(U @ Vt) >= 0 else -1.0
        R = (U * D) @ Vt
        t = mp - R @ mq
        var_p = self.sum_pp - self.count * mp @ mp
        var_q = self.sum_qq - self.count * mq @ mq
        residual = max(0.0, float(var_p + var_q - 2.0 * np.sum(sv * D)))
        return RigidTransform(R, t, residual)


def align_points(p: np.ndarray, q: np.ndarray) -> RigidTransform:
    """Optimal rigid transform with p ~ R q + t for matched points (m, d) (via :class:`AlignmentStats`)."""
    return AlignmentStats.from_points(p, q).solve()


def merge_point_pairs(pos_a: np.ndarray, rot_a: np.ndarray, pos_b: np.ndarray, rot_b: np.ndarray,
                      z_ab: np.ndarray, z_ba: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Matched points of Algorithm 1 lines 7-8 for the observation pairs across a cut.

    Parameters
    ----------
    pos_a, rot_a : ndarray, shapes (m, d), (m, d, d)
        Pose of the A-side module of each crossing pair, in A's frame.
    pos_b, rot_b : ndarray, shapes (m, d), (m, d, d)
        Pose of the B-side module of each crossing pair, in B's frame.
    z_ab, z_ba : ndarray, shape (m, d)
        The pair's observations z_{a,b} (in a's local frame) and z_{b,a} (in b's local frame).

    Returns
    -------
    p, q : ndarray, shape (2 m, d)
        Points in A's frame and their matches in B's frame. Under the model (eq. 1) each module sees
        its neighbour's centre at twice its sensor offset, so every pair gives two matches: the centre
        of b as predicted by a (in A) with b's centre (in B), and a's centre (in A) with a's centre as
        predicted by b (in B). Their midpoints are the matched sensors of Funiak et al. 2008, and a single pair
        already fixes the planar rotation.
    """
    pa_b = pos_a + 2.0 * np.einsum("mab,mb->ma", rot_a, z_ab)
    pb_a = pos_b + 2.0 * np.einsum("mab,mb->ma", rot_b, z_ba)
    return np.concatenate([pa_b, pos_a]), np.concatenate([pos_b, pb_a])
