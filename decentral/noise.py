"""The noise levels that weight the relative-localization factors (standard library only, so that the
command line can show their defaults without importing numpy)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["NoiseModel"]


@dataclass(frozen=True)
class NoiseModel:
    """Noise levels used to weight the factors (``weighting="information"``) or not (``"unit"``).

    Attributes
    ----------
    sigma_pixel : float
        Std. of a detection's centre (u, v), pixels.
    sigma_radius : float
        Std. of a detection's radius, pixels.
    sigma_odom_p : float
        Std. of each odometry translation component per step, metres.
    sigma_odom_theta : float
        Std. of the odometry yaw increment per step, radians.
    weighting : {"information", "unit"}
        ``unit`` gives every residual weight 1, as Liu et al. 2024 eq. (5) and (8) do.
    """

    sigma_pixel: float = 1.0
    sigma_radius: float = 0.5
    sigma_odom_p: float = 0.005
    sigma_odom_theta: float = 0.005
    weighting: str = "information"

    def __post_init__(self) -> None:
        if self.weighting not in ("information", "unit"):
            raise ValueError(f"weighting must be 'information' or 'unit', got {self.weighting!r}")
        for name in ("sigma_pixel", "sigma_radius", "sigma_odom_p", "sigma_odom_theta"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive")

    def odometry_weights(self) -> tuple[float, float]:
        """(translation weight, rotation weight); ``||R2(d) - I||_F^2 ~= 2 d^2`` fixes the latter's 1/2."""
        if self.weighting == "unit":
            return 1.0, 1.0
        return 1.0 / self.sigma_odom_p**2, 0.5 / self.sigma_odom_theta**2
