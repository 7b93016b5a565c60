"""Sine fit of the structure displacement (paper Eq. 2 and 13).

Model: Y_s(t) = A sin(2 pi f t + phi) + B with t the absolute camera time (s), Y in mm.
Internally the fit uses a centred time t - t_ref for conditioning (phase psi about t_ref);
``phase_rad`` and ``cov`` are reported about t = 0 as the contract wants.
Velocities and accelerations are returned in m/s and m/s^2 (:func:`vibro_model.units.mm_to_m`);
:meth:`StructureFit.motion` gives the SI model type.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from vibro_model.codec import none_if_nan
from vibro_model.errors import RecordingError
from vibro_model.results import StructureMotion
from vibro_model.units import mm_to_m


@dataclass(frozen=True, kw_only=True)
class StructureFit:
    """The sine fit of the structure track (mm) with its covariance, also about the reference time the fit used
    (for error propagation). ``cov`` is the 4x4 covariance of (amplitude_mm, frequency_hz, phase_rad, offset_mm).
    Not the model type: :meth:`motion` gives the SI :class:`~vibro_model.results.StructureMotion`."""

    amplitude_mm: float
    frequency_hz: float
    phase_rad: float
    offset_mm: float
    cov: np.ndarray
    rms_residual_mm: float
    n_points: int
    t_ref_s: float = 0.0
    params_ref: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # (A mm, f Hz, psi rad, B mm) about t_ref
    cov_ref: np.ndarray | None = None  # covariance of params_ref

    def position_mm(self, t_s: np.ndarray | float) -> np.ndarray | float:
        """Y_s(t) in mm."""
        a, f, psi, b = self.params_ref
        return a * np.sin(2.0 * np.pi * f * (np.asarray(t_s) - self.t_ref_s) + psi) + b

    def velocity_mps(self, t_s: np.ndarray | float) -> np.ndarray | float:
        """dY_s/dt in m/s."""
        a, f, psi, _ = self.params_ref
        w = 2.0 * np.pi * f
        return mm_to_m(a * w * np.cos(w * (np.asarray(t_s) - self.t_ref_s) + psi))

    def acceleration_mps2(self, t_s: np.ndarray | float) -> np.ndarray | float:
        """d2Y_s/dt2 in m/s^2."""
        a, f, psi, _ = self.params_ref
        w = 2.0 * np.pi * f
        return -mm_to_m(a * w * w * np.sin(w * (np.asarray(t_s) - self.t_ref_s) + psi))

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of (amplitude_mm, frequency_hz, phase_rad, offset_mm)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))

    def motion(self, ball_offset_mm: float | None = None, moving: bool = True) -> StructureMotion:
        """The fitted sine as the model type (SI; stds from the covariance, None without one). A structure
        that does not move beyond DIC noise (``moving`` False) has no frequency or phase: a sine fitted to
        noise would claim one. ``ball_offset_mm``: ball centre minus cavity centre at frame 0 (mm)."""
        sd = [None] * 4 if self.cov is None else [none_if_nan(v) for v in self.std]
        freq, phase = none_if_nan(self.frequency_hz), none_if_nan(self.phase_rad)
        note = ""
        if not moving:
            freq = phase = sd[1] = sd[2] = None
            note = "the structure does not move beyond DIC noise: no frequency or phase"
        return StructureMotion(amplitude_m=mm_to_m(none_if_nan(self.amplitude_mm)), frequency_hz=freq, phase_rad=phase,
                               offset_m=mm_to_m(none_if_nan(self.offset_mm)),
                               rms_residual_m=mm_to_m(none_if_nan(self.rms_residual_mm)),
                               amplitude_std_m=mm_to_m(sd[0]), frequency_std_hz=sd[1], phase_std_rad=sd[2],
                               offset_std_m=mm_to_m(sd[3]), n_points=int(self.n_points),
                               ball_offset_m=mm_to_m(none_if_nan(ball_offset_mm)), moving=bool(moving), note=note)


def _model(p: np.ndarray, tc: np.ndarray) -> np.ndarray:
    return p[0] * np.sin(2.0 * np.pi * p[1] * tc + p[2]) + p[3]


def _jac(p: np.ndarray, tc: np.ndarray) -> np.ndarray:
    arg = 2.0 * np.pi * p[1] * tc + p[2]
    s, c = np.sin(arg), np.cos(arg)
    return np.column_stack([s, p[0] * c * 2.0 * np.pi * tc, p[0] * c, np.ones_like(tc)])


def spectral_peak_hz(t_s: np.ndarray, y: np.ndarray, pad: int = 16, f_min_hz: float | None = None) -> float:
    """Dominant frequency (Hz) of a sampled signal: zero-padded, Hann-windowed FFT + parabolic peak on log |X|.

    Samples may have gaps: the signal is linearly resampled on the median time step first.
    """
    t_s = np.asarray(t_s, float)
    y = np.asarray(y, float)
    dt = float(np.median(np.diff(t_s)))
    grid = np.arange(t_s[0], t_s[-1] + 0.5 * dt, dt)
    yg = np.interp(grid, t_s, y)
    yg = (yg - yg.mean()) * np.hanning(yg.size)
    n = int(2 ** math.ceil(math.log2(yg.size * pad)))
    mag = np.abs(np.fft.rfft(yg, n))
    freqs = np.fft.rfftfreq(n, dt)
    lo = f_min_hz if f_min_hz is not None else 1.5 / (grid[-1] - grid[0] + dt)
    mag[freqs < lo] = 0.0
    k = int(np.argmax(mag))
    if 0 < k < mag.size - 1 and mag[k - 1] > 0 and mag[k + 1] > 0:
        l0, l1, l2 = np.log(mag[k - 1]), np.log(mag[k]), np.log(mag[k + 1])
        den = l0 - 2.0 * l1 + l2
        delta = 0.5 * (l0 - l2) / den if den != 0 else 0.0
        return float(freqs[k] + delta * (freqs[1] - freqs[0]))
    return float(freqs[k])


def fit_structure(t_s: np.ndarray, y_mm: np.ndarray, f0_hz: float | None = None,
                  t_ref_s: float | None = None) -> StructureFit:
    """Least-squares sine fit (Eq. 13) of the structure displacement y_mm (mm) at times t_s (s).

    The start frequency is ``f0_hz`` when given, else the refined spectral peak. Amplitude and phase
    start from the linear fit at that frequency. NaN samples are ignored. Raises RecordingError when
    fewer than 8 finite samples remain.
    """
    t_s = np.asarray(t_s, float)
    y_mm = np.asarray(y_mm, float)
    ok = np.isfinite(t_s) & np.isfinite(y_mm)
    t, y = t_s[ok], y_mm[ok]
    if t.size < 8:
        raise RecordingError(f"structure fit: only {t.size} valid structure samples (need at least 8)")
    if t_ref_s is None:
        t_ref_s = 0.5 * (t[0] + t[-1])
    tc = t - t_ref_s
    f0 = float(f0_hz) if f0_hz else spectral_peak_hz(t, y)
    w0 = 2.0 * np.pi * f0
    design = np.column_stack([np.sin(w0 * tc), np.cos(w0 * tc), np.ones_like(tc)])
    (cs, cc, off), *_ = np.linalg.lstsq(design, y, rcond=None)
    p0 = np.array([math.hypot(cs, cc), f0, math.atan2(cc, cs), off])
    if p0[0] == 0.0:
        p0[0] = 1e-6
    res = least_squares(lambda p: _model(p, tc) - y, p0, jac=lambda p: _jac(p, tc), method="lm",
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    p = res.x.copy()
    if p[0] < 0:
        p[0] = -p[0]
        p[2] += np.pi
    p[2] = (p[2] + np.pi) % (2.0 * np.pi) - np.pi
    r = _model(p, tc) - y
    dof = max(t.size - 4, 1)
    s2 = float(r @ r) / dof
    jm = _jac(p, tc)
    try:
        cov_ref = s2 * np.linalg.inv(jm.T @ jm)
    except np.linalg.LinAlgError:
        cov_ref = np.full((4, 4), np.nan)
    # phase about t = 0: phi = psi - 2 pi f t_ref
    phi = p[2] - 2.0 * np.pi * p[1] * t_ref_s
    tr = np.eye(4)
    tr[2, 1] = -2.0 * np.pi * t_ref_s
    cov = tr @ cov_ref @ tr.T
    return StructureFit(
        amplitude_mm=float(p[0]), frequency_hz=float(p[1]),
        phase_rad=float((phi + np.pi) % (2.0 * np.pi) - np.pi), offset_mm=float(p[3]),
        cov=cov, rms_residual_mm=float(np.sqrt(np.mean(r * r))), n_points=int(t.size),
        t_ref_s=float(t_ref_s), params_ref=tuple(float(v) for v in p), cov_ref=cov_ref,
    )


def with_params(fit: StructureFit, params_ref: np.ndarray) -> StructureFit:
    """A copy of ``fit`` with other (A, f, psi, B) about the same t_ref (used for error propagation)."""
    return StructureFit(amplitude_mm=fit.amplitude_mm, frequency_hz=fit.frequency_hz, phase_rad=fit.phase_rad,
                        offset_mm=fit.offset_mm, cov=fit.cov,
                        rms_residual_mm=fit.rms_residual_mm, n_points=fit.n_points, t_ref_s=fit.t_ref_s,
                        params_ref=tuple(float(v) for v in params_ref), cov_ref=fit.cov_ref)
