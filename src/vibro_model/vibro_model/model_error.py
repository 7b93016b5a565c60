"""What a model leaves in its residuals, as an uncertainty of the velocities it gives (issue 39).

A COR's sigma propagated from the fits' covariances (DIC noise through the flight parabolas and the structure
fit) holds what white noise does to the velocities, nothing else. Where the model describes the motion only
approximately (a force the parabola or the catalogue does not hold, a harmonic below the selection's floor, a
plate that creeps, DIC's sub-pixel bias) the residuals hold a smooth part as well, and the velocities the model
gives at the impacts are off by that part's slope there: a referee was told a precision 10-100x better than the
measurement had (2-sigma coverage 0.44-0.71 on such recordings, against 0.92-1.00 where the model fits).

The rule, the same for every model (the paper's parabolas, the discrepancy analysis' final model):

- **a flight**: its residuals over its frames are fitted with Legendre polynomials P0..P3 in
  x = 2 (tau - mid) / T; the slope of the smooth part c2 P2 + c3 P3 at the impact, ``d``, is how far the
  model's velocity there is from the measured motion, with ``sd`` its sigma from the residual scatter
  (:func:`flight_residual_slope`). A parabola absorbs P0..P2, so for the paper only a cubic remains; a flight
  of the final model has only its state free (P0, P1), so a flight-to-flight change of the force shows as P2;
- **the structure**: its residual within one drive period of the impact, fitted with an offset, a drift and a
  sine and cosine of the drive, gives the slope at the impact (:func:`local_sine_slope`);
- one flight's slope is a noisy estimate (a cubic's end slope has several times the sigma of the model's own
  velocity), so the squared bias is pooled over the impacts of a kind, per plate and side (the flight before,
  the flight after, the structure), and counted only where it is significant (:func:`pooled_bias_variance`: a
  mean slope of one sign, or a scatter of the slopes beyond their sigmas): a model that fits keeps its sigma,
  and what a model leaves is told more finely as the impacts accumulate;
- the pooled variances join each impact's velocity variances before the COR's (Eq. 16) first-order
  propagation (:meth:`ModelError.cor_variance`).

Plain numpy, SI or track units as the caller's (the slope is in the residual's unit per second).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

#: fewer frames in a flight: no residual shape (a cubic needs room to be told from noise)
MIN_FLIGHT_FRAMES = 8
#: fewer structure frames within one drive period of an impact: no local structure slope
MIN_STRUCTURE_FRAMES = 12
#: half the window (drive periods) of a local structure fit with a changing drive (``local_sine_slope`` with
#: ``ramp``) at an impact: half a period either side follows a drive's amplitude ramp of 0.1 s (2.2 periods) to
#: ~0.07 mm/s, where one period either side missed it by up to 1.4 mm/s (a COR error of 0.003 inside the ramp), and
#: costs ~1.5x the noise of a steady drive's velocity (~0.012 mm/s, far below a COR's); vibro_fit.drive_velocity and
#: vibro_discrepancy.reidentify.structure_misfit use it
LOCAL_HALF_WINDOW_PERIODS = 0.5
#: fewer impacts of a kind (plate and side): no pooled bias (a model error needs several impacts to be told)
MIN_POOL = 5
#: a pooled bias counts beyond this many of its standard errors (the false-alarm rate of a 3-sigma test)
SIGNIFICANCE = 3.0


def _slope_of_fit(X: np.ndarray, r: np.ndarray, grad: np.ndarray) -> tuple[float, float]:
    """(grad . coef, its 1-sigma) of the least-squares fit r ~ X coef, sigma^2 from the fit's residuals; NaN when
    singular or without degrees of freedom."""
    dof = r.size - X.shape[1]
    if dof < 1:
        return math.nan, math.nan
    coef, *_ = np.linalg.lstsq(X, r, rcond=None)
    s2 = float(np.sum((r - X @ coef) ** 2)) / dof
    try:
        cov = s2 * np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        return math.nan, math.nan
    return float(grad @ coef), math.sqrt(max(float(grad @ cov @ grad), 0.0))


def flight_residual_slope(tau_s: np.ndarray, residual: np.ndarray, tau_at_s: float) -> tuple[float, float]:
    """(d, sd): the slope at ``tau_at_s`` (residual unit / s) of the P2 + P3 part of the flight's ``residual``
    fitted with Legendre P0..P3 over its span (module docstring), and its 1-sigma. NaN with fewer than
    :data:`MIN_FLIGHT_FRAMES` finite frames or a span of zero."""
    tau, r = np.asarray(tau_s, dtype=float), np.asarray(residual, dtype=float)
    ok = np.isfinite(tau) & np.isfinite(r)
    tau, r = tau[ok], r[ok]
    if tau.size < MIN_FLIGHT_FRAMES or not tau.max() > tau.min():
        return math.nan, math.nan
    mid, half = 0.5 * (tau.max() + tau.min()), 0.5 * (tau.max() - tau.min())
    x = (tau - mid) / half
    X = np.column_stack([np.ones_like(x), x, 0.5 * (3 * x ** 2 - 1), 0.5 * (5 * x ** 3 - 3 * x)])
    xa = (float(tau_at_s) - mid) / half
    # d/dtau of P2 and P3 at xa: P2' = 3 x, P3' = (15 x^2 - 3) / 2, times dx/dtau = 1 / half
    grad = np.array([0.0, 0.0, 3.0 * xa, 0.5 * (15.0 * xa ** 2 - 3.0)]) / half
    return _slope_of_fit(X, r, grad)


def local_sine_slope(tau_s: np.ndarray, residual: np.ndarray, omega_rad_s: float,
                     ramp: bool = False) -> tuple[float, float]:
    """(d, sd): the slope at tau = 0 (residual unit / s) of c0 + c1 tau + a sin(w tau) + b cos(w tau) fitted to a
    structure model's ``residual`` around the impact (tau = t - t_impact, within about one drive period), and its
    1-sigma; with ``ramp``, (a + a1 tau) and (b + b1 tau): a drive changing across the window. NaN with fewer than
    :data:`MIN_STRUCTURE_FRAMES` finite frames or a singular fit."""
    tau, r = np.asarray(tau_s, dtype=float), np.asarray(residual, dtype=float)
    ok = np.isfinite(tau) & np.isfinite(r)
    tau, r = tau[ok], r[ok]
    if tau.size < MIN_STRUCTURE_FRAMES:
        return math.nan, math.nan
    w = float(omega_rad_s)
    s, c = np.sin(w * tau), np.cos(w * tau)
    cols = [np.ones_like(tau), tau, s, c] + ([tau * s, tau * c] if ramp else [])
    grad = [0.0, 1.0, w, 0.0] + ([0.0, 1.0] if ramp else [])
    return _slope_of_fit(np.column_stack(cols), r, np.array(grad))


def pooled_bias_variance(slopes: Iterable[tuple[float, float]]) -> float:
    """The mean squared bias the (d, sd) slopes of impacts of one kind show, where it is significant: the larger
    of the squared mean slope (a bias of one sign: mean(d)^2 - SE^2 when |mean(d)| > :data:`SIGNIFICANCE` SE,
    SE^2 = mean(sd^2) / n) and the excess scatter (a bias that changes from impact to impact: mean(d^2) -
    mean(sd^2) when above :data:`SIGNIFICANCE` of its own standard error sqrt(2 / n) mean(sd^2)). 0 with fewer
    than :data:`MIN_POOL` finite pairs or nothing significant: one flight's slope is several times noisier than
    the model's velocity, and a noise-sized estimate would swamp the sigma of a model that fits."""
    pairs = np.array([(d, sd) for d, sd in slopes if math.isfinite(d) and math.isfinite(sd)], dtype=float)
    n = pairs.shape[0]
    if n < MIN_POOL:
        return 0.0
    d, sd2 = pairs[:, 0], float(np.mean(pairs[:, 1] ** 2))
    mean, se2 = float(np.mean(d)), sd2 / n
    one_sign = mean * mean - se2 if mean * mean > SIGNIFICANCE ** 2 * se2 else 0.0
    excess = float(np.mean(d * d)) - sd2
    scatter = excess if excess > SIGNIFICANCE * math.sqrt(2.0 / n) * sd2 else 0.0
    return max(one_sign, scatter, 0.0)


@dataclass(frozen=True)
class ImpactSlopes:
    """The residual slopes (d, sd) at one impact (velocity units): the flight before, the flight after and the
    structure (NaN: unknown), and the impact's plate."""

    plate: str
    before: tuple[float, float]
    after: tuple[float, float]
    structure: tuple[float, float]


SIDES = ("before", "after", "structure")


@dataclass(frozen=True)
class ModelError:
    """The pooled squared velocity biases per plate: {plate: (before, after, structure)} (velocity units^2)."""

    variances: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)

    @classmethod
    def of(cls, slopes: Sequence[ImpactSlopes]) -> "ModelError":
        """Pooled per plate and side (:func:`pooled_bias_variance`)."""
        out, counts = {}, {}
        for plate in sorted({s.plate for s in slopes}):
            kind = [s for s in slopes if s.plate == plate]
            out[plate] = tuple(pooled_bias_variance(getattr(s, side) for s in kind) for side in SIDES)
            counts[plate] = len(kind)
        return cls(variances=out, counts=counts)

    def cor_variance(self, plate: str, v_before: float, v_after: float, v_structure: float,
                     structure: bool = True) -> float:
        """The COR variance the pooled biases of ``plate`` give an impact with these velocities; ``structure``
        False leaves the structure's out (an impact measured with a structure fit local to it)."""
        vb, va, vs = self.variances.get(plate, (0.0, 0.0, 0.0))
        return cor_variance_of_biases(v_before, v_after, v_structure, vb, va, vs if structure else 0.0)

    def to_dict(self, unit_per_s: str = "mps") -> dict:
        """{plate: {rms_bias_before_<unit>, ..._after_, ..._structure_, impacts}} (the RMS velocity biases)."""
        return {p: {**{f"rms_bias_{side}_{unit_per_s}": math.sqrt(v) for side, v in zip(SIDES, var)},
                    "impacts": self.counts.get(p, 0)} for p, var in self.variances.items()}


def cor_variance_of_biases(v_before: float, v_after: float, v_structure: float, var_before: float,
                           var_after: float, var_structure: float) -> float:
    """The COR's variance (Eq. 16, e = -(v_after - v_s) / (v_before - v_s), first order) from independent bias
    variances of the three velocities (m^2/s^2): de/dv_before = (v_after - v_s) / (v_before - v_s)^2,
    de/dv_after = -1 / (v_before - v_s), de/dv_s = (v_before - v_after) / (v_before - v_s)^2."""
    den = v_before - v_structure
    if den == 0 or not math.isfinite(den):
        return 0.0
    g_b = (v_after - v_structure) / den ** 2
    g_a = -1.0 / den
    g_s = (v_before - v_after) / den ** 2
    return g_b * g_b * var_before + g_a * g_a * var_after + g_s * g_s * var_structure
