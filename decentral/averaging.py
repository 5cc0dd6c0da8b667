"""Average consensus: the pure reduction behind a gather/broadcast round.

Each agent ``i`` holds a value ``x_i`` and, after a round, its neighbours' values (fresh or stale).
One step of linear average consensus with Metropolis-Hastings weights [1]_:

.. math::

    x_i \\leftarrow x_i + \\sum_{j \\in N_i} w_{ij} (x_j - x_i), \\qquad
    w_{ij} = \\frac{1}{1 + \\max(d_i, d_j)},

which keeps the network average invariant when every message arrives (the weights are symmetric) and
converges to it on a connected graph. A neighbour whose value is missing contributes nothing that
round (its weight is folded into the self weight), so lost messages slow the iteration but never make
it diverge.

References
----------
.. [1] L. Xiao, S. Boyd, S. Lall, "A scheme for robust distributed sensor fusion based on average
   consensus", IPSN 2005.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

__all__ = ["metropolis_weight", "consensus_step"]


def metropolis_weight(degree_i: int, degree_j: int) -> float:
    """Metropolis-Hastings weight of the edge ``(i, j)`` given both degrees."""
    return 1.0 / (1.0 + max(int(degree_i), int(degree_j)))


def consensus_step(
    x_i: np.ndarray,
    neighbours: Mapping[str, np.ndarray],
    weights: Mapping[str, float],
) -> np.ndarray:
    """One average-consensus update of agent ``i``.

    Parameters
    ----------
    x_i : ndarray, shape (...)
        The agent's current value.
    neighbours : Mapping[str, ndarray]
        Values received this round (fresh or stale), same shape as ``x_i``; absent neighbours are skipped.
    weights : Mapping[str, float]
        ``w_ij`` for every neighbour (with ``sum_j w_ij < 1``).

    Returns
    -------
    ndarray, shape (...)
        The updated value (a new array).
    """
    x_i = np.asarray(x_i, dtype=float)
    out = x_i.copy()
    for name, x_j in neighbours.items():
        out += weights[name] * (np.asarray(x_j, dtype=float) - x_i)
    return out
