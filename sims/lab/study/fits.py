"""Least-squares fits users ask of scaling results: ``a + b ln N`` and the power law ``c N^p``.

Both report R² on ``y`` itself (not on its logarithm), so the two are comparable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Fit", "fit_log", "fit_power"]


@dataclass(frozen=True)
class Fit:
    """A fitted curve.

    Attributes
    ----------
    kind : str
        ``"log"`` (y = a + b ln N) or ``"power"`` (y = a N^b).
    a, b : float
        Its coefficients.
    r2 : float
        Coefficient of determination on y.
    points : int
        Samples fitted.
    """

    kind: str
    a: float
    b: float
    r2: float
    points: int

    def __call__(self, n: np.ndarray) -> np.ndarray:
        n = np.asarray(n, float)
        return self.a + self.b * np.log(n) if self.kind == "log" else self.a * n ** self.b

    def formula(self, y: str = "y") -> str:
        """The fit as text, e.g. ``y = -3025 + 642 ln N``."""
        if self.kind == "log":
            return f"{y} = {self.a:.4g} {'+' if self.b >= 0 else '-'} {abs(self.b):.4g} ln N"
        return f"{y} = {self.a:.4g} N^{self.b:.3f}"


def _r2(y: np.ndarray, pred: np.ndarray) -> float:
    ss_res = float(np.sum((y - pred) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0


def _clean(n, y) -> tuple[np.ndarray, np.ndarray]:
    n, y = np.asarray(n, float), np.asarray(y, float)
    keep = np.isfinite(n) & np.isfinite(y) & (n > 0)
    return n[keep], y[keep]


def fit_log(n, y) -> Fit | None:
    """Least-squares ``y = a + b ln n`` over samples (n, y); ``None`` with fewer than 2 distinct n."""
    n, y = _clean(n, y)
    if np.unique(n).size < 2:
        return None
    A = np.column_stack([np.ones(n.size), np.log(n)])
    (a, b), *_ = np.linalg.lstsq(A, y, rcond=None)
    return Fit("log", float(a), float(b), _r2(y, A @ np.array([a, b])), int(n.size))


def fit_power(n, y) -> Fit | None:
    """Least-squares ``ln y = ln a + b ln n`` (positive y only); R² on y. ``None`` if underdetermined."""
    n, y = _clean(n, y)
    keep = y > 0
    n, y = n[keep], y[keep]
    if np.unique(n).size < 2:
        return None
    A = np.column_stack([np.ones(n.size), np.log(n)])
    (la, b), *_ = np.linalg.lstsq(A, np.log(y), rcond=None)
    a = float(np.exp(la))
    return Fit("power", a, float(b), _r2(y, a * n ** b), int(n.size))
