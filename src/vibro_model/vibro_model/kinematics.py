"""Prescribed motion of the structure (the cavity centre), SI units, positive up: the one kinematic type
that the simulator, the fit results (:meth:`vibro_model.results.StructureMotion.kinematics`), the synthetic
rig's truth (:meth:`StructureKinematics.from_mm`) and the discrepancy analysis share.

Paper Eq. 2: Y_s(t) = A sin(w t + phi) + B, optionally with 2nd/3rd harmonics:

    theta = w t + phi
    Y_s(t) = B + A [sin(theta) + r2 sin(2 theta + phi2) + r3 sin(3 theta + phi3)]

The harmonic phases are relative to the fundamental's phase (so ``phase_rad`` shifts
the whole waveform in time) and ``h2_ratio``/``h3_ratio`` are amplitude ratios to A.

:class:`StructureWithTone` adds a tone at any frequency (not a drive harmonic): the synthetic rig's
``structure_tone`` effect, and the discrepancy analysis' model of a located one
(:mod:`vibro_discrepancy.tone`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from vibro_model.units import mm_to_m

ArrayLike = "float | np.ndarray"
#: the types of one instant that StructureKinematics evaluates in floats
_SCALARS = (float, np.float64)


@dataclass(frozen=True)
class StructureKinematics:
    """Structure displacement Y_s(t) (m), velocity (m/s), acceleration (m/s^2); t in s."""

    amplitude_m: float
    frequency_hz: float
    phase_rad: float = 0.0
    offset_m: float = 0.0
    h2_ratio: float = 0.0
    h3_ratio: float = 0.0
    h2_phase_rad: float = 0.0
    h3_phase_rad: float = 0.0

    def __post_init__(self) -> None:
        for name in ("amplitude_m", "frequency_hz", "phase_rad", "offset_m", "h2_ratio",
                     "h3_ratio", "h2_phase_rad", "h3_phase_rad"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"StructureKinematics.{name} must be finite, got {value!r}")
        if self.frequency_hz <= 0:
            raise ValueError(f"StructureKinematics.frequency_hz must be > 0, got {self.frequency_hz}")
        if self.amplitude_m < 0:
            raise ValueError(f"StructureKinematics.amplitude_m must be >= 0, got {self.amplitude_m}")

    @classmethod
    def from_mm(cls, structure: Mapping[str, Any]) -> "StructureKinematics":
        """The motion a contract mapping in mm describes (a truth file's ``structure``: ``amplitude_mm``,
        ``frequency_hz``, ``phase_rad``, optional ``offset_mm`` (0), ``h2_ratio``, ``h3_ratio``,
        ``h2_phase_rad``, ``h3_phase_rad`` (0)), lengths converted to m."""
        harmonics = {k: float(structure.get(k, 0.0)) for k in ("h2_ratio", "h3_ratio", "h2_phase_rad", "h3_phase_rad")}
        return cls(mm_to_m(float(structure["amplitude_mm"])), float(structure["frequency_hz"]),
                   float(structure["phase_rad"]), mm_to_m(float(structure.get("offset_mm", 0.0))), **harmonics)

    @property
    def harmonic_terms(self) -> tuple[tuple[int, float, float], ...]:
        """(k, amplitude ratio to A, phase rad relative to k theta) of the fundamental and harmonics 2 and 3."""
        return ((1, 1.0, 0.0), (2, self.h2_ratio, self.h2_phase_rad), (3, self.h3_ratio, self.h3_phase_rad))

    @property
    def omega_rad_s(self) -> float:
        """Angular frequency w = 2 pi f (rad/s)."""
        return 2.0 * math.pi * self.frequency_hz

    def _sum(self, t, order: int):
        """Sum of the n-th time derivative of the three harmonics (without offset)."""
        if type(t) in _SCALARS:   # one instant (a contact integration asks ~300 times per impact): no arrays
            return self._sum_at(t, order)
        t = np.asarray(t, dtype=float)
        w = self.omega_rad_s
        theta = w * t + self.phase_rad
        if self.h2_ratio == 0.0 and self.h3_ratio == 0.0:
            out = (self.amplitude_m * w ** order) * np.sin(theta + order * 0.5 * math.pi)
            return out if out.ndim else float(out)
        out = np.zeros_like(theta)
        for k, ratio, ph in self.harmonic_terms:
            if ratio == 0.0:
                continue
            arg = k * theta + ph
            # d^n/dt^n sin(k w t + c) = (k w)^n sin(k w t + c + n pi/2)
            out = out + ratio * (k * w) ** order * np.sin(arg + order * 0.5 * math.pi)
        out = self.amplitude_m * out
        return out if out.ndim else float(out)

    def _sum_at(self, t: float, order: int) -> float:
        """:meth:`_sum` at one instant ``t`` (s), in floats (the same terms in the same order)."""
        w = self.omega_rad_s
        theta = w * t + self.phase_rad
        shift = order * 0.5 * math.pi
        if self.h2_ratio == 0.0 and self.h3_ratio == 0.0:
            return (self.amplitude_m * w ** order) * math.sin(theta + shift)
        out = 0.0
        for k, ratio, ph in self.harmonic_terms:
            if ratio != 0.0:
                out = out + ratio * (k * w) ** order * math.sin(k * theta + ph + shift)
        return self.amplitude_m * out

    def position(self, t):
        """Y_s(t) in m (scalar or array like ``t``)."""
        return self._sum(t, 0) + self.offset_m

    def velocity(self, t):
        """dY_s/dt in m/s."""
        return self._sum(t, 1)

    def acceleration(self, t):
        """d2Y_s/dt2 in m/s^2."""
        return self._sum(t, 2)

    def jerk(self, t):
        """d3Y_s/dt3 in m/s^3."""
        return self._sum(t, 3)

    def bound(self, order: int) -> float:
        """Upper bound of |d^n Y_s/dt^n| over all t (sum of harmonic magnitudes)."""
        w = self.omega_rad_s
        return self.amplitude_m * sum(abs(r) * (k * w) ** order for k, r, _ in self.harmonic_terms)

    def to_dict(self) -> dict:
        """Plain mapping of the parameters (SI)."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class StructureWithTone(StructureKinematics):
    """StructureKinematics plus a tone of ``tone_amplitude_m`` at ``tone_frequency_hz`` (any frequency)."""

    tone_amplitude_m: float = 0.0
    tone_frequency_hz: float = 0.0
    tone_phase_rad: float = 0.0

    def _sum(self, t, order: int):
        base = super()._sum(t, order)
        w = 2.0 * math.pi * self.tone_frequency_hz
        tone = self.tone_amplitude_m * w ** order * np.sin(w * np.asarray(t, dtype=float) + self.tone_phase_rad
                                                           + order * 0.5 * math.pi)
        out = base + tone
        return out if np.ndim(out) else float(out)

    def bound(self, order: int) -> float:
        return super().bound(order) + self.tone_amplitude_m * (2.0 * math.pi * self.tone_frequency_hz) ** order


#: bounds over all u of |d^n/du^n (1 + tanh u) / 2|, n = 0..4 (the maxima are 1, 1/2, 0.385, 1, 2.07: rounded up)
_STEP_BOUNDS = (1.0, 0.5, 0.39, 1.0, 2.1)


def _logistic(u, order: int):
    """d^order/du^order of (1 + tanh u) / 2 (order 0..4), written in T = tanh u."""
    T = np.tanh(u)
    q = 1.0 - T * T
    return (0.5 * (1.0 + T), 0.5 * q, -T * q, (3.0 * T * T - 1.0) * q, (8.0 * T - 12.0 * T ** 3) * q)[order]


@dataclass(frozen=True)
class DriveChange(StructureKinematics):
    """StructureKinematics whose drive does not hold still: the amplitude steps smoothly from ``amplitude_m`` to
    ``amplitude_m (1 + step_ratio)`` around ``step_time_s`` (logistic, 2 % to 98 % of the step within ``ramp_s``)
    and the frequency drifts linearly by ``drift_hz_per_s`` from ``frequency_hz`` at t = 0::

        A(t) = A0 [1 + r (1 + tanh(4 (t - t_step) / ramp)) / 2],  f(t) = f0 + k t
        theta(t) = phase + 2 pi (f0 t + k t^2 / 2)                (the integral of the frequency)
        Y_s(t) = B + A(t) [sin(theta) + r2 sin(2 theta + p2) + r3 sin(3 theta + p3)]

    Derivatives are exact (of the complex envelope A e^(i k theta)). ``bound`` holds for |t| <= ``horizon_s``
    (a drifting frequency has no bound over all time): a simulation must stay inside it."""

    step_ratio: float = 0.0
    step_time_s: float = 0.0
    ramp_s: float = 0.1
    drift_hz_per_s: float = 0.0
    horizon_s: float = 100.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.ramp_s > 0 or not self.horizon_s > 0 or not self.step_ratio > -1.0:
            raise ValueError(f"DriveChange: ramp_s and horizon_s must be > 0 and step_ratio > -1, got "
                             f"{self.ramp_s}, {self.horizon_s}, {self.step_ratio}")
        if self.frequency_hz - abs(self.drift_hz_per_s) * self.horizon_s <= 0:
            raise ValueError("DriveChange: the drifting frequency reaches 0 Hz within the horizon")

    def amplitude_at(self, t, order: int = 0):
        """d^order A / dt^order (m / s^order) at ``t`` (order 0..4)."""
        tau = 0.25 * self.ramp_s
        u = (np.asarray(t, dtype=float) - self.step_time_s) / tau
        out = self.amplitude_m * self.step_ratio * _logistic(u, order) / tau ** order
        return out + self.amplitude_m if order == 0 else out

    def frequency_at(self, t):
        """The instantaneous frequency f0 + k t (Hz)."""
        return self.frequency_hz + self.drift_hz_per_s * np.asarray(t, dtype=float)

    def _sum(self, t, order: int):
        t = np.asarray(t, dtype=float)
        theta = self.phase_rad + 2.0 * math.pi * (self.frequency_hz * t + 0.5 * self.drift_hz_per_s * t * t)
        w = 2.0 * math.pi * self.frequency_at(t)
        dw = 2.0 * math.pi * self.drift_hz_per_s
        a = [self.amplitude_at(t, n) for n in range(order + 1)]
        out = np.zeros_like(theta)
        for k, ratio, ph in self.harmonic_terms:
            if ratio != 0.0:
                out = out + ratio * _envelope_derivative(a, k * w, k * dw, k * theta + ph, order)
        return out if out.ndim else float(out)

    def bound(self, order: int) -> float:
        w = 2.0 * math.pi * (self.frequency_hz + abs(self.drift_hz_per_s) * self.horizon_s)
        dw = 2.0 * math.pi * abs(self.drift_hz_per_s)
        tau = 0.25 * self.ramp_s
        a = [self.amplitude_m * (1.0 + max(self.step_ratio, 0.0))]
        a += [self.amplitude_m * abs(self.step_ratio) * _STEP_BOUNDS[n] / tau ** n for n in range(1, order + 1)]
        return sum(abs(ratio) * _envelope_bound(a, k * w, k * dw, order) for k, ratio, _ in self.harmonic_terms)


def _envelope_terms(order: int) -> list[tuple[int, int, int, int, int]]:
    """d^n/dt^n [A e^(i theta)] = e^(i theta) sum c i^m A^(j) w^p (w')^q with w = theta' and w' constant: the
    terms (c, m, j, p, q) of n = ``order``, by the recursion P_(n+1) = d/dt P_n + i w P_n from P_0 = A."""
    terms = {(0, 0, 0, 0): 1}
    for _ in range(order):
        new: dict[tuple[int, int, int, int], int] = {}
        for (m, j, p, q), c in terms.items():
            for key, cc in (((m, j + 1, p, q), c), ((m, j, p - 1, q + 1), c * p), ((m + 1, j, p + 1, q), c)):
                if cc:
                    new[key] = new.get(key, 0) + cc
        terms = new
    return [(c, m, j, p, q) for (m, j, p, q), c in terms.items()]


def _envelope_derivative(a, w, dw, theta, order: int):
    """Im(d^n/dt^n [A e^(i theta)]) with ``a`` = [A, A', ...], ``w`` = theta', ``dw`` = theta''."""
    out = 0.0
    for c, m, j, p, q in _envelope_terms(order):
        out = out + c * a[j] * w ** p * dw ** q * np.sin(theta + 0.5 * math.pi * m)   # Im(i^m e^(i theta))
    return out


def _envelope_bound(a, w: float, dw: float, order: int) -> float:
    """An upper bound of |d^n/dt^n [A e^(i theta)]| from bounds ``a`` of |A^(j)| and of |w|, |w'| (term by term)."""
    return float(sum(abs(c) * a[j] * w ** p * dw ** q for c, m, j, p, q in _envelope_terms(order)))
