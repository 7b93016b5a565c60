"""The synthetic ball's in-plane spin: a spin rate per flight, set anew at each impact.

Convention: the angle is the rotation of the ball's speckle texture about its centre in the
image plane, in rad, positive COUNTER-CLOCKWISE as the camera sees the image, 0 at frame 0
(camera time 0). The spin does not act on the translation (the flights and impact times are
those of the scenario without it).

Model (options of :class:`.scenario.SynthConfig`): the flight after simulated impact n (n
counting every impact from the start of the lead-in) spins at s[n + 1] rad/s, and the ball
starts the lead-in at s[0], with s[k] = ``spin_rad_s`` + ``spin_sigma_rad_s`` z_k, z_k ~ N(0, 1)
from the seed (independent of every other draw). Impact n changes the spin by
ds_n = s[n + 1] - s[n]. With ``spin_cor_coupling_s_per_rad`` = k != 0 impact n's COR is the
scenario's law + k ds_n (clipped to [0, 1]): an impact that changes the spin more restitutes
differently, the case where the COR scatter correlates with the spin change.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..restitution import RestitutionLaw

MAX_IMPACTS = 100_000


def spin_sequence(mean_rad_s: float, sigma_rad_s: float, seed: int, n: int = MAX_IMPACTS + 1) -> np.ndarray:
    """s[k] (rad/s): the spin of the flight after simulated impact k - 1 (s[0]: before the first)."""
    z = np.random.default_rng([seed, 31337]).standard_normal(n) if sigma_rad_s > 0 else np.zeros(n)
    return mean_rad_s + sigma_rad_s * z


@dataclass(frozen=True)
class SpinCoupled(RestitutionLaw):
    """e_n = base(...) + coupling_s_per_rad (s[n + 1] - s[n]), clipped to [0, 1]."""

    base: RestitutionLaw
    spins_rad_s: np.ndarray
    coupling_s_per_rad: float

    @property
    def effect(self) -> str:  # type: ignore[override]
        return getattr(self.base, "effect", "none")

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        e = self.base.cor(plate, v_rel_mps, impact_index)
        k = impact_index % (len(self.spins_rad_s) - 1)
        change = float(self.spins_rad_s[k + 1] - self.spins_rad_s[k])
        return float(min(1.0, max(0.0, e + self.coupling_s_per_rad * change)))

    def parameters(self) -> dict:
        return dict(self.base.parameters(), spin_cor_coupling_s_per_rad=self.coupling_s_per_rad)


def spin_rate(t_s, impact_t_s: np.ndarray, impact_index: np.ndarray, spins_rad_s: np.ndarray) -> np.ndarray:
    """Spin (rad/s) at times ``t_s``: s[index of the last impact before t + 1], s[0] before any."""
    order = np.argsort(impact_t_s)
    times = np.asarray(impact_t_s, dtype=float)[order]
    after = np.asarray(impact_index, dtype=int)[order] + 1
    k = np.searchsorted(times, np.asarray(t_s, dtype=float), side="left")  # impacts strictly before t
    idx = np.where(k > 0, after[np.maximum(k - 1, 0)], 0)
    return spins_rad_s[idx]


def spin_angle(t_s, impact_t_s: np.ndarray, impact_index: np.ndarray, spins_rad_s: np.ndarray) -> np.ndarray:
    """Angle (rad, + counter-clockwise on screen) at times ``t_s``: the integral of the spin from t = 0."""
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    times = np.sort(np.asarray(impact_t_s, dtype=float))

    def integral(x: np.ndarray) -> np.ndarray:
        """Integral of the spin from the earliest of 0, x and the impacts to x (exact: piecewise constant)."""
        t_lo = min(0.0, float(x.min()), float(times[0]) if times.size else 0.0) - 1.0
        knots = np.concatenate([[t_lo], times])
        rates = spin_rate(knots + 1e-12, impact_t_s, impact_index, spins_rad_s)
        # cumulative angle at each knot
        cum = np.concatenate([[0.0], np.cumsum(rates[:-1] * np.diff(knots))])
        j = np.searchsorted(knots, x, side="right") - 1
        return cum[j] + rates[j] * (x - knots[j])

    both = integral(np.concatenate([t, [0.0]]))
    out = both[:-1] - both[-1]
    return out if np.ndim(t_s) else out[0]
