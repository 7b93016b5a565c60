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
    def omega_rad_s(self) -> float:
        """Angular frequency w = 2 pi f (rad/s)."""
        return 2.0 * math.pi * self.frequency_hz

    def _sum(self, t, order: int):
        """Sum of the n-th time derivative of the three harmonics (without offset)."""
        t = np.asarray(t, dtype=float)
        w = self.omega_rad_s
        theta = w * t + self.phase_rad
        if self.h2_ratio == 0.0 and self.h3_ratio == 0.0:
            out = (self.amplitude_m * w ** order) * np.sin(theta + order * 0.5 * math.pi)
            return out if out.ndim else float(out)
        out = np.zeros_like(theta)
        for k, ratio, ph in ((1, 1.0, 0.0), (2, self.h2_ratio, self.h2_phase_rad),
                             (3, self.h3_ratio, self.h3_phase_rad)):
            if ratio == 0.0:
                continue
            arg = k * theta + ph
            # d^n/dt^n sin(k w t + c) = (k w)^n sin(k w t + c + n pi/2)
            out = out + ratio * (k * w) ** order * np.sin(arg + order * 0.5 * math.pi)
        out = self.amplitude_m * out
        return out if out.ndim else float(out)

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
        return self.amplitude_m * sum(abs(r) * (k * w) ** order
                                      for k, r in ((1, 1.0), (2, self.h2_ratio), (3, self.h3_ratio)))

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
