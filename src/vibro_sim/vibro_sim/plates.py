"""A plate that moves against the structure, as the event simulator reads it (``plates`` of
:func:`vibro_sim.cor_model.simulate_cor`).

Y_plate(t) = Y_s(t) + p(t - t_ref) (m), p a polynomial (coefficients in m, highest power first): a creeping plate
(the synthetic rig's ``plate_creep``, a line through 0 at camera time 0) or the creep the identification measured
(:mod:`vibro_fit.plate_motion`, results.json ``plate_motion``). The simulator needs, besides the position and
its derivatives, bounds on the derivatives' magnitudes over the time it simulates (its contact scan steps by
them): a polynomial's own are taken over ``span_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def _max_abs(coef: np.ndarray, lo: float, hi: float) -> float:
    """Max |q(x)| over [lo, hi] of the polynomial ``coef`` (a constant or a line: inf for an unbounded span)."""
    if coef.size == 0 or not np.any(coef):
        return 0.0
    if coef.size == 1:
        return float(abs(coef[0]))
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return math.inf
    xs = [lo, hi] + [float(r.real) for r in np.roots(np.polyder(coef)) if abs(r.imag) < 1e-12 and lo < r.real < hi]
    return float(max(abs(np.polyval(coef, x)) for x in xs))


@dataclass(frozen=True)
class MovedPlate:
    """A plate at the structure's motion plus ``coef_m`` (a polynomial in t - ``t_ref_s``, m; highest power first),
    with derivative bounds valid over ``span_s`` (s of t)."""

    structure: object
    coef_m: tuple[float, ...]
    t_ref_s: float = 0.0
    span_s: tuple[float, float] = (-math.inf, math.inf)

    def _term(self, t, order: int):
        coef = np.asarray(self.coef_m, dtype=float)
        for _ in range(order):
            coef = np.polyder(coef)
        return np.polyval(coef, np.asarray(t, dtype=float) - self.t_ref_s) if coef.size else 0.0

    def position(self, t):
        return self.structure.position(t) + self._term(t, 0)

    def velocity(self, t):
        return self.structure.velocity(t) + self._term(t, 1)

    def acceleration(self, t):
        return self.structure.acceleration(t) + self._term(t, 2)

    def jerk(self, t):
        return self.structure.jerk(t) + self._term(t, 3)

    def bound(self, order: int) -> float:
        """A bound on |d^order Y_plate / dt^order| over ``span_s``."""
        coef = np.asarray(self.coef_m, dtype=float)
        for _ in range(order):
            coef = np.polyder(coef)
        lo, hi = self.span_s
        return self.structure.bound(order) + _max_abs(coef, lo - self.t_ref_s, hi - self.t_ref_s)

    @property
    def frequency_hz(self) -> float:
        return self.structure.frequency_hz
