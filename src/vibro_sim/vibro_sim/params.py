"""Physical parameters of the ball and the cavity (SI units)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from vibro_model.constants import G_MPS2

# Paper's Appendix A / Test 1 rig: ceramic ball, aluminium plates.
BALL_MASS_KG = 1.82e-4
BALL_DIAMETER_M = 4.77e-3
BALL_E_PA = 3.1e11
BALL_NU = 0.27
PLATE_E_PA = 7.0e10
PLATE_NU = 0.33
GAP_M = 16.6e-3


@dataclass(frozen=True, kw_only=True)
class BallCavity:
    """A ball of mass m and radius R in a cavity with free play b (m) each side of centre.

    The ball centre touches the upper plate at Y_b - Y_s = +b and the lower at -b.
    ``tilt_deg`` tilts the motion axis from vertical: effective gravity g cos(tilt) (90: a horizontal axis, no
    gravity along it; beyond 90 the upper plate is the lower one: gravity pulls towards it).
    Material data (Young's moduli in Pa, Poisson ratios) feed the Hertz contact.
    """

    mass_kg: float = BALL_MASS_KG
    radius_m: float = 0.5 * BALL_DIAMETER_M
    free_play_m: float = 0.5 * (GAP_M - BALL_DIAMETER_M)
    gravity_mps2: float = G_MPS2
    tilt_deg: float = 0.0
    ball_E_pa: float = BALL_E_PA
    ball_nu: float = BALL_NU
    plate_E_pa: float = PLATE_E_PA
    plate_nu: float = PLATE_NU

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"BallCavity.{name} must be a finite number, got {value!r}")
        for name in ("mass_kg", "radius_m", "free_play_m", "ball_E_pa", "plate_E_pa"):
            if getattr(self, name) <= 0:
                raise ValueError(f"BallCavity.{name} must be > 0, got {getattr(self, name)}")
        for name in ("ball_nu", "plate_nu"):
            if not -1.0 < getattr(self, name) < 0.5:
                raise ValueError(f"BallCavity.{name} must be in (-1, 0.5), got {getattr(self, name)}")
        if self.gravity_mps2 < 0:
            raise ValueError(f"BallCavity.gravity_mps2 must be >= 0, got {self.gravity_mps2}")
        if not -180.0 <= self.tilt_deg <= 180.0:
            raise ValueError(f"BallCavity.tilt_deg must be in [-180, 180], got {self.tilt_deg}")

    @property
    def g_eff_mps2(self) -> float:
        """Gravity along the motion axis, g cos(tilt) (m/s^2, pulls down; exactly 0 for a horizontal axis)."""
        if abs(self.tilt_deg) == 90.0:
            return 0.0
        return self.gravity_mps2 * math.cos(math.radians(self.tilt_deg))

    @property
    def effective_modulus_pa(self) -> float:
        """Hertz E* = 1 / ((1 - nu_b^2)/E_b + (1 - nu_s^2)/E_s) (Pa)."""
        return 1.0 / ((1 - self.ball_nu ** 2) / self.ball_E_pa + (1 - self.plate_nu ** 2) / self.plate_E_pa)

    @property
    def contact_stiffness(self) -> float:
        """Hertz K of Eq. 8 (N/m^1.5): 4 R^0.5 / (3 pi (k_b + k_s)), k_i = (1 - nu_i^2)/(pi E_i)."""
        k_b = (1 - self.ball_nu ** 2) / (math.pi * self.ball_E_pa)
        k_s = (1 - self.plate_nu ** 2) / (math.pi * self.plate_E_pa)
        return 4.0 * math.sqrt(self.radius_m) / (3.0 * math.pi * (k_b + k_s))

    @classmethod
    def from_rig(cls, rig, gravity_mps2: float = G_MPS2, tilt_deg: float | None = None) -> "BallCavity":
        """Build from a :class:`vibro_io.rig.RigConfig` (mm in the rig -> m here); ``tilt_deg`` None: the rig's
        declared orientation, rig.yaml ``setup.axis_tilt_deg``."""
        if tilt_deg is None:
            setup = getattr(rig, "setup", None)
            tilt_deg = float(setup.axis_tilt_deg) if setup is not None else 0.0
        return cls(
            mass_kg=rig.ball.mass_kg,
            radius_m=0.5e-3 * rig.ball.diameter_mm,
            free_play_m=1e-3 * rig.free_play_mm,
            gravity_mps2=gravity_mps2,
            tilt_deg=tilt_deg,
            ball_E_pa=rig.ball.youngs_modulus_pa,
            ball_nu=rig.ball.poisson_ratio,
            plate_E_pa=rig.structure.youngs_modulus_pa,
            plate_nu=rig.structure.poisson_ratio,
        )
