"""The drive as it moved over a take: the identified sine times a slowly varying envelope (issue 38).

The identification's windowed drive (:mod:`vibro_fit.drive`, results.json ``drive``) fits the structure track in
windows of a few drive cycles. Where it finds that the drive did not hold still, the replay (Eq. 18's D) must
not drive the simulated cavity with the take's average sine: a 10 % amplitude step makes the simulated plate
miss the measured one by 5 % of the amplitude for half the take. :class:`DriveEnvelope` is the windows'
amplitude ratio, phase shift and offset shift against the global sine at the windows' centres, interpolated
linearly in between (held outside); :class:`EnvelopedDrive` is the motion it gives::

    theta(t) = w t + phi + dphi(t),  Y_s(t) = B + dB(t) + r(t) A [sin(theta) + r2 sin(2 theta + p2) + r3 ...]

with r, dphi, dB piecewise linear (their second derivatives vanish inside a segment), so the n-th derivative is
exactly ``n r' S_(n-1) theta'^(n-1) + r S_n theta'^n (+ dB' for n = 1)``, S_n the n-th derivative of the
harmonic sum in theta. A stationary drive (or one not tested) has no envelope: the global sine stays.
Units: m, s, rad.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from vibro_model.kinematics import StructureKinematics
from vibro_model.units import mm_to_m


@dataclass(frozen=True)
class DriveEnvelope:
    """The windows' amplitude ratio, phase shift (rad) and offset shift (m) against the global sine at their
    centre times ``t_s`` (s, increasing; at least two)."""

    t_s: tuple[float, ...]
    amplitude_ratio: tuple[float, ...]
    phase_shift_rad: tuple[float, ...]
    offset_shift_m: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.t_s)
        if n < 2 or any(len(x) != n for x in (self.amplitude_ratio, self.phase_shift_rad, self.offset_shift_m)):
            raise ValueError(f"DriveEnvelope: needs >= 2 windows and equal lengths, got {n}, "
                             f"{len(self.amplitude_ratio)}, {len(self.phase_shift_rad)}, {len(self.offset_shift_m)}")
        arrays = np.array([self.t_s, self.amplitude_ratio, self.phase_shift_rad, self.offset_shift_m], dtype=float)
        if not np.all(np.isfinite(arrays)):
            raise ValueError("DriveEnvelope: every window value must be finite")
        if np.any(np.diff(arrays[0]) <= 0):
            raise ValueError("DriveEnvelope: window times must increase")
        if np.any(arrays[1] < 0):
            raise ValueError("DriveEnvelope: amplitude ratios must be >= 0")

    @classmethod
    def of_drive_section(cls, drive: Mapping[str, Any] | None, offset_m: float) -> "DriveEnvelope | None":
        """The envelope of results.json's ``drive`` section when the drive was found not stationary (None when
        stationary, not tested, absent or without usable windows). ``offset_m``: the global sine's offset B (m,
        the ``structure`` section's), against which the windows' offsets are shifts."""
        if not isinstance(drive, Mapping) or drive.get("stationary") is not False:
            return None
        glob = drive.get("global") or {}
        amplitude_mm, phase_rad = glob.get("amplitude_mm"), glob.get("phase_rad")
        rows = [w for w in drive.get("windows") or () if isinstance(w, Mapping)
                and all(isinstance(w.get(k), (int, float)) for k in ("t_s", "amplitude_mm", "phase_rad", "offset_mm"))]
        number = (int, float)
        if not isinstance(amplitude_mm, number) or not amplitude_mm > 0 or not isinstance(phase_rad, number) \
                or len(rows) < 2:
            return None
        rows.sort(key=lambda w: w["t_s"])
        return cls(t_s=tuple(float(w["t_s"]) for w in rows),
                   amplitude_ratio=tuple(float(w["amplitude_mm"]) / amplitude_mm for w in rows),
                   phase_shift_rad=tuple(float(w["phase_rad"]) - phase_rad for w in rows),
                   offset_shift_m=tuple(mm_to_m(float(w["offset_mm"])) - offset_m for w in rows))

    def demodulated(self, t_s: np.ndarray, y_m: np.ndarray, offset_m: float, frequency_hz: float
                    ) -> tuple[np.ndarray, np.ndarray]:
        """A structure track (``t_s`` s, ``y_m`` m) as the global sine (offset ``offset_m``, ``frequency_hz``) would
        show it without this envelope: each sample at the time t + dphi(t) / w where the global phase is its
        phase, its offset shift taken off and its distance from the offset divided by the amplitude ratio
        (time s, position m). What the harmonics of a drive that moved are fitted on: the global sine's
        harmonic columns then see the drive's own shape, not its change."""
        t = np.asarray(t_s, dtype=float)
        ratio = np.interp(t, self.t_s, self.amplitude_ratio)
        shift = np.interp(t, self.t_s, self.phase_shift_rad)
        d_offset = np.interp(t, self.t_s, self.offset_shift_m)
        y = (np.asarray(y_m, dtype=float) - offset_m - d_offset) / np.where(ratio > 0, ratio, 1.0) + offset_m
        return t + shift / (2.0 * math.pi * frequency_hz), y

    def applied_to(self, motion: StructureKinematics) -> "EnvelopedDrive":
        """``motion`` (the global sine, with its harmonics) under this envelope."""
        return EnvelopedDrive(**motion.to_dict(), envelope=self)


def under_envelope(motion: StructureKinematics, envelope: DriveEnvelope | None) -> StructureKinematics:
    """``motion`` under ``envelope`` (:meth:`DriveEnvelope.applied_to`), or ``motion`` itself where the drive held
    still (``envelope`` None)."""
    return motion if envelope is None else envelope.applied_to(motion)


def _segments(x: tuple[float, ...], y: tuple[float, ...], t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(value, slope) of the piecewise-linear interpolation of (x, y) at ``t``, held constant outside."""
    xs, ys = np.asarray(x), np.asarray(y)
    value = np.interp(t, xs, ys)
    k = np.clip(np.searchsorted(xs, t, side="right"), 1, xs.size - 1)
    slope = (ys[k] - ys[k - 1]) / (xs[k] - xs[k - 1])
    return value, np.where((t < xs[0]) | (t > xs[-1]), 0.0, slope)


@dataclass(frozen=True)
class EnvelopedDrive(StructureKinematics):
    """:class:`StructureKinematics` under a :class:`DriveEnvelope` (module docstring); exact derivatives."""

    envelope: DriveEnvelope | None = None

    def _harmonics(self, theta: np.ndarray, order: int) -> np.ndarray:
        """S_order(theta): the order-th theta-derivative of A [sin(theta) + r2 sin(2 theta + p2) + ...]."""
        out = np.zeros_like(theta)
        for k, ratio, ph in self.harmonic_terms:
            if ratio != 0.0:
                out = out + ratio * k ** order * np.sin(k * theta + ph + order * 0.5 * math.pi)
        return self.amplitude_m * out

    def _scalar(self, t: float, order: int) -> float:
        """:meth:`_sum` at one time (the simulator's event loop asks one time at a time: plain floats, no arrays)."""
        env = self.envelope
        x = env.t_s
        k = min(max(bisect_right(x, t), 1), len(x) - 1)
        inside = x[0] <= t <= x[-1]

        def segment(y: tuple[float, ...]) -> tuple[float, float]:
            if not inside:
                return (y[0] if t < x[0] else y[-1]), 0.0
            slope = (y[k] - y[k - 1]) / (x[k] - x[k - 1])
            return y[k - 1] + slope * (t - x[k - 1]), slope

        r, dr = segment(env.amplitude_ratio)
        dphi, ddphi = segment(env.phase_shift_rad)
        theta = self.omega_rad_s * t + self.phase_rad + dphi
        rate = self.omega_rad_s + ddphi

        def harmonics(n: int) -> float:
            out = 0.0
            for h, ratio, ph in self.harmonic_terms:
                if ratio != 0.0:
                    out += ratio * h ** n * math.sin(h * theta + ph + n * 0.5 * math.pi)
            return self.amplitude_m * out

        out = r * harmonics(order) * rate ** order
        if order >= 1:
            out += order * dr * harmonics(order - 1) * rate ** (order - 1)
        if order <= 1:
            shift, dshift = segment(env.offset_shift_m)
            out += shift if order == 0 else dshift
        return out

    def _sum(self, t, order: int):
        env = self.envelope
        if env is not None and np.ndim(t) == 0:
            return self._scalar(float(t), order)
        t = np.asarray(t, dtype=float)
        if env is None:
            return super()._sum(t, order)
        r, dr = _segments(env.t_s, env.amplitude_ratio, t)
        dphi, ddphi = _segments(env.t_s, env.phase_shift_rad, t)
        theta = self.omega_rad_s * t + self.phase_rad + dphi
        rate = self.omega_rad_s + ddphi
        out = r * self._harmonics(theta, order) * rate ** order
        if order >= 1:
            out = out + order * dr * self._harmonics(theta, order - 1) * rate ** (order - 1)
        if order == 0 or order == 1:
            shift, dshift = _segments(env.t_s, env.offset_shift_m, t)
            out = out + (shift if order == 0 else dshift)
        return out if out.ndim else float(out)

    def bound(self, order: int) -> float:
        env = self.envelope
        if env is None:
            return super().bound(order)
        t = np.asarray(env.t_s)
        slope = lambda y: np.abs(np.diff(np.asarray(y)) / np.diff(t))  # noqa: E731
        w = self.omega_rad_s + float(slope(env.phase_shift_rad).max())
        harm = [self.amplitude_m * sum(abs(r) * k ** n for k, r, _ in self.harmonic_terms) for n in range(order + 1)]
        out = max(env.amplitude_ratio) * harm[order] * w ** order
        if order >= 1:
            out += order * float(slope(env.amplitude_ratio).max()) * harm[order - 1] * w ** (order - 1)
        if order == 1:
            out += float(slope(env.offset_shift_m).max())
        return out

    def to_dict(self) -> dict:
        """The global sine's parameters (SI), as :class:`StructureKinematics` gives them (no envelope)."""
        return {k: getattr(self, k) for k in StructureKinematics.__dataclass_fields__}
