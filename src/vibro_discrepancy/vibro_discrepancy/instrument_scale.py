"""The image scale as an instrument parameter: the flights' apparent gravity (issue 38).

A scale ``camera.mm_per_px`` off by a relative ``e`` multiplies every displacement by ``1 + e``: the flights then
fall at ``g (1 + e)``. The COR, a ratio of velocities, does not see it; the flight force terms do: a scale 0.3 %
off is a constant acceleration of 0.03 m/s^2, which the library fits as a tilt, or, where the selection takes
another term first, as drag (a wrong claim). ``vibro init`` measures the scale with a relative sigma
(rig.yaml ``camera.mm_per_px_rel_std``), so the size of the scale error is known before the analysis.

Before the discrepancy analysis looks for missing physics, :func:`scale_from_flights` estimates the apparent
gravity from the flights with every flight term of the library free (a drag or a Coulomb friction does not bias
it then: they are other columns of the same regression) and weighs it against the scale's prior ``N(0,
sigma_s^2)``:

- the measured relative change ``e_hat +- s_e`` is consistent with the prior when ``|e_hat| <=``
  :data:`SCALE_SIGMAS` ``sqrt(sigma_s^2 + s_e^2)``; the analysis then runs with gravity ``g (1 + e_post)``,
  ``e_post = e_hat sigma_s^2 / (sigma_s^2 + s_e^2)`` (the posterior mean), and says so in the discrepancy's
  ``instrument_scale`` block: it is the instrument, never a finding;
- beyond, the gravity change is left to the findings (a tilt, a force): a scale error cannot make it.

Without a stated scale sigma (a synthetic rig's exact scale, a hand-written rig.yaml without
``mm_per_px_rel_std``) nothing changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from vibro_discrepancy.data import Measured
from vibro_discrepancy.fitting import fit_flights
from vibro_discrepancy.library import FLIGHT_TERMS, GravityTilt
from vibro_model.codec import json_number

#: a gravity change within this many combined sigmas (scale prior and estimate) is the scale's
SCALE_SIGMAS = 3.0
#: the fit's gravity ceiling, in scale sigmas above g: the tilt column (>= 0) lowers it to the apparent gravity
CEILING_SIGMAS = SCALE_SIGMAS + 3.0
#: fewer free flights than this: no estimate (the flights' terms cannot be separated)
MIN_FLIGHTS = 6


@dataclass(frozen=True)
class InstrumentScale:
    """The flights' apparent gravity against rig.yaml's scale uncertainty.

    ``relative_change`` e_hat (apparent / nominal gravity - 1) with its sigma ``relative_change_std``;
    ``scale_rel_std`` sigma_s (rig.yaml); ``absorbed``: e_hat within :data:`SCALE_SIGMAS` combined sigmas, so the
    analysis used ``gravity_used_mps2`` = g (1 + e_post)."""

    nominal_g_mps2: float
    relative_change: float
    relative_change_std: float
    scale_rel_std: float
    absorbed: bool
    gravity_used_mps2: float

    @property
    def limit(self) -> float:
        """The largest |e_hat| taken as the scale's (relative)."""
        return SCALE_SIGMAS * math.hypot(self.scale_rel_std, self.relative_change_std)

    def words(self) -> str:
        e, s = 100 * self.relative_change, 100 * self.relative_change_std
        head = (f"the flights fall at {self.nominal_g_mps2 * (1 + self.relative_change):.4g} m/s^2, "
                f"{e:+.2f} % +- {s:.2f} % from g along the axis")
        if self.absorbed:
            return (f"{head}: within {SCALE_SIGMAS:g} sigmas of the image scale's uncertainty "
                    f"({100 * self.scale_rel_std:.2f} %, rig.yaml camera.mm_per_px_rel_std), taken as the scale "
                    f"(off by about {100 * (self.gravity_used_mps2 / self.nominal_g_mps2 - 1):+.2f} %), not as "
                    "physics; the CORs do not depend on the scale")
        return (f"{head}: beyond what the image scale's uncertainty ({100 * self.scale_rel_std:.2f} %) allows "
                f"({100 * self.limit:.2f} %); left to the findings")

    def to_dict(self) -> dict:
        return {"nominal_gravity_mps2": json_number(self.nominal_g_mps2),
                "relative_change": json_number(self.relative_change),
                "relative_change_std": json_number(self.relative_change_std),
                "scale_rel_std": json_number(self.scale_rel_std), "limit": json_number(self.limit),
                "absorbed": self.absorbed, "gravity_used_mps2": json_number(self.gravity_used_mps2),
                "words": self.words()}


def apparent_gravity(meas: Measured, ceiling_mps2: float) -> tuple[float, float] | None:
    """(apparent gravity, its sigma) in m/s^2 from the flights with every library flight term free: gravity
    ``ceiling_mps2`` minus the constant (tilt) column's coefficient (at the ceiling when the data would put it above:
    the coefficient is held >= 0 on a vertical rig, and the gate then finds it beyond the scale's reach). None when
    the fit cannot separate the terms (a singular covariance)."""
    fit = fit_flights(meas, FLIGHT_TERMS, g_mps2=ceiling_mps2)
    k = next(i for i, t in enumerate(fit.terms) if isinstance(t, GravityTilt))
    c = float(fit.coefs[k])
    var = float(fit.cov[k, k]) if fit.cov.size else math.inf
    if not (math.isfinite(var) and var > 0):
        return None
    return ceiling_mps2 - c, math.sqrt(var)


def scale_from_flights(meas: Measured) -> tuple[Measured, InstrumentScale | None]:
    """``meas`` with the flights' gravity the scale's where the scale's uncertainty explains it (module
    docstring), and the estimate; ``(meas, None)`` without a stated scale sigma, without gravity along the axis
    or with too few flights."""
    sigma_s, g = float(meas.scale_rel_std), float(meas.g_mps2)
    if sigma_s <= 0 or g <= 0 or len(meas.flights) < MIN_FLIGHTS:
        return meas, None
    est = apparent_gravity(meas, g * (1.0 + CEILING_SIGMAS * sigma_s))
    if est is None:
        return meas, None
    e_hat, s_e = est[0] / g - 1.0, est[1] / g
    absorbed = abs(e_hat) <= SCALE_SIGMAS * math.hypot(sigma_s, s_e)
    e_post = e_hat * sigma_s ** 2 / (sigma_s ** 2 + s_e ** 2) if absorbed else 0.0
    scale = InstrumentScale(nominal_g_mps2=g, relative_change=e_hat, relative_change_std=s_e, scale_rel_std=sigma_s,
                            absorbed=absorbed, gravity_used_mps2=g * (1.0 + e_post))
    if not absorbed:
        return meas, scale
    return replace(meas, g_mps2=scale.gravity_used_mps2, notes=[*meas.notes, scale.words()]), scale

