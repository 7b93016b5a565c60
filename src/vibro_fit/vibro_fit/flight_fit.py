"""Parabola per free flight (paper Eq. 3, 14) and friction per flight (Eq. 17).

Each flight is fitted in centred time tc = t - t_ref (t_ref = mid time of its frames) for
conditioning: Y[mm] = A tc^2 + B tc + C, with the covariance s^2 (X^T X)^-1, s^2 = SSR / (n - 3).
:meth:`FlightFit.abs_coefficients` gives a, b, c for Y[mm] = a t^2 + b t + c with t the absolute
camera time (s), as results.json wants; :meth:`FlightFit.model` gives the SI model type. Velocities and
accelerations are returned in m/s and m/s^2 (:func:`vibro_model.units.mm_to_m` of the mm/s terms).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vibro_model.codec import none_if_nan
from vibro_model.constants import G_MPS2
from vibro_model.results import Flight
from vibro_model.units import mm_to_m


@dataclass(kw_only=True)
class FlightFit:
    """The parabola fit of one flight in track units (mm, centred time) with its covariance, the segmentation's
    verdict (free or not, why) and its frames (track indices); ``coef`` = (A, B, C) about ``t_ref_s``.
    Not the model type: :meth:`model` gives the SI :class:`~vibro_model.results.Flight`."""

    index: int
    frames: np.ndarray
    t_start_s: float
    t_end_s: float
    t_ref_s: float
    coef: np.ndarray
    cov: np.ndarray
    rms_residual_mm: float
    n_points: int
    fitted: bool = True
    is_free: bool = True
    reason: str = ""
    direction: str = ""      # "up" | "down" | "" (unknown)
    notes: list[str] = field(default_factory=list)

    def position_mm(self, t_s: np.ndarray | float) -> np.ndarray | float:
        tc = np.asarray(t_s) - self.t_ref_s
        return (self.coef[0] * tc + self.coef[1]) * tc + self.coef[2]

    def velocity_mps(self, t_s: np.ndarray | float) -> np.ndarray | float:
        """Ball velocity (m/s)."""
        tc = np.asarray(t_s) - self.t_ref_s
        return mm_to_m(2.0 * self.coef[0] * tc + self.coef[1])

    @property
    def acceleration_mps2(self) -> float:
        return 2.0 * mm_to_m(float(self.coef[0]))

    @property
    def acceleration_std_mps2(self) -> float:
        return 2.0 * mm_to_m(float(np.sqrt(max(self.cov[0, 0], 0.0))))

    def friction_n(self, mass_kg: float, g_mps2: float = G_MPS2) -> tuple[float, float]:
        """Eq. 17: F = m (2a + g) (N, positive up) and its standard deviation (N); ``g_mps2`` the gravity along
        the motion axis, g cos(setup.axis_tilt_deg) (:attr:`vibro_io.rig.RigConfig.g_axis_mps2`)."""
        return mass_kg * (self.acceleration_mps2 + g_mps2), mass_kg * self.acceleration_std_mps2

    def abs_coefficients(self) -> tuple[float, float, float]:
        """(a, b, c) for Y[mm] = a t^2 + b t + c, t absolute camera time (s)."""
        a_, b_, c_ = (float(v) for v in self.coef)
        r = self.t_ref_s
        return a_, b_ - 2.0 * a_ * r, a_ * r * r - b_ * r + c_

    def model(self, mass_kg: float, g_mps2: float = G_MPS2) -> Flight:
        """The fitted flight as the model type (SI, NaN -> None); friction from Eq. 17 with the ball mass
        ``mass_kg`` and the gravity along the axis ``g_mps2`` (m/s^2), only for a free flight."""
        a, b, c = (mm_to_m(none_if_nan(v)) for v in self.abs_coefficients())
        f_n, f_std = self.friction_n(mass_kg, g_mps2)
        return Flight(index=int(self.index), t_first_frame_s=none_if_nan(self.t_start_s),
                      t_last_frame_s=none_if_nan(self.t_end_s), a_mps2=a, b_mps=b, c_m=c,
                      direction=self.direction or "", friction_n=none_if_nan(f_n) if self.is_free else None,
                      friction_std_n=none_if_nan(f_std) if self.is_free else None,
                      rms_residual_m=mm_to_m(none_if_nan(self.rms_residual_mm)),
                      n_points=int(self.n_points), free=bool(self.is_free), reason=self.reason or "")


def fit_parabola(t_s: np.ndarray, y_mm: np.ndarray, weights: np.ndarray | None = None
                 ) -> tuple[float, np.ndarray, np.ndarray, float]:
    """Least-squares parabola in centred time. Returns (t_ref, coef, cov, rms_residual_mm).

    With ``weights`` (inverse variances, relative) the fit is weighted and the covariance scaled by
    the weighted residual variance.
    """
    t_s = np.asarray(t_s, float)
    y_mm = np.asarray(y_mm, float)
    t_ref = 0.5 * (t_s[0] + t_s[-1])
    tc = t_s - t_ref
    x = np.column_stack([tc * tc, tc, np.ones_like(tc)])
    w = np.ones_like(tc) if weights is None else np.asarray(weights, float)
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(x * sw[:, None], y_mm * sw, rcond=None)
    r = y_mm - x @ coef
    dof = max(t_s.size - 3, 1)
    s2 = float(np.sum(w * r * r)) / dof
    cov = s2 * np.linalg.inv((x * w[:, None]).T @ x)
    return t_ref, coef, cov, float(np.sqrt(np.mean(r * r)))


def fit_flight(index: int, frames: np.ndarray, t_s: np.ndarray, y_mm: np.ndarray, min_points: int = 6,
               weights: np.ndarray | None = None) -> FlightFit:
    """Fit one flight on the given frame indices (into t_s / y_mm). Flights with fewer than
    ``min_points`` frames are returned with ``fitted=False`` (reported, not fitted)."""
    frames = np.asarray(frames, int)
    t, y = t_s[frames], y_mm[frames]
    if frames.size < max(min_points, 4):
        return FlightFit(index=index, frames=frames, t_start_s=float(t[0]) if t.size else float("nan"),
                         t_end_s=float(t[-1]) if t.size else float("nan"), t_ref_s=float("nan"),
                         coef=np.full(3, np.nan),
                         cov=np.full((3, 3),
                                     np.nan), rms_residual_mm=float("nan"), n_points=int(frames.size), fitted=False,
                         is_free=False, reason=f"too few points ({frames.size} < {min_points})")
    t_ref, coef, cov, rms = fit_parabola(t, y, None if weights is None else weights[frames])
    return FlightFit(index=index, frames=frames, t_start_s=float(t[0]), t_end_s=float(t[-1]), t_ref_s=t_ref, coef=coef,
                     cov=cov, rms_residual_mm=rms, n_points=int(frames.size))
