"""decentral: the mathematics of decentralized, multi-observer relative localization.

This package holds only numerics (numpy, scipy, cvxpy/Clarabel, networkx): geometry, factors,
the relaxation and its rounding, ADMM, normalized cut, alignment and metrics. It performs no I/O.
"""

from decentral.errors import DecentralError, InputError, ProtocolError, SolverError

__all__ = ["DecentralError", "InputError", "ProtocolError", "SolverError"]
