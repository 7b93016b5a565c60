"""Does the drive hold still? The structure track fitted in sliding windows, and a test with two floors.

The paper describes the structure by one sine over the whole take (Eq. 2, fitted by Eq. 13:
:func:`vibro_fit.structure_fit.fit_structure`). A shaker under closed-loop control need not hold one amplitude
over a long take (a lab saw it change by ~10 % once in 20 s), nor one frequency; one global sine then
averages over the change, and what it leaves looks like side bands of the drive (a "tone" next to the drive
frequency). This module fits the drive piecewise and says whether it moved:

1. **Windows.** The good frames cut into consecutive windows of :data:`WINDOW_CYCLES` drive cycles (the
   global fit's frequency f_g; 4 cycles = 0.18 s at 22 Hz: short enough to place a change to a fraction of a
   second, long enough to hold ~180 frames, so an amplitude to ~0.1 % of itself). Each window is a linear
   least-squares fit Y = a sin(w (t - t_c)) + b cos(w (t - t_c)) + c about its centre t_c (plus the 2nd and 3rd
   harmonics, :data:`WINDOW_HARMONICS`, so that a distorted drive's harmonics are not taken for noise), with covariance
   s^2 (X^T X)^-1 (s^2 the window's residual variance): amplitude hypot(a, b), phase atan2(b, a), offset c
   with their standard deviations. The phase is reported about t = 0 at the global frequency,
   phase_k = psi_k - 2 pi f_g t_c (unwrapped around the global phase): a stationary drive gives the global
   phase in every window.
2. **Phase and frequency.** The phase deviations phase_k - phase_g fitted by a weighted quadratic in time
   (a linear drift of the frequency is a quadratic phase; a line is only a constant frequency a little off the
   global fit's, which a stationary drive may show): drift k = c2 / pi Hz/s. The phase has *moved* when the
   quadratic's improvement over a line is significant (F-test on 1 and m - 3 degrees of freedom, family-wise
   ``ALPHA``) AND the excursion the curvature leaves about its best line over the take (``span_rad``, no single
   sine follows it) exceeds :data:`PHASE_FLOOR_RAD` (5 mrad: a phase error that shifts an impact by 36 us at
   22 Hz, below a frame) and 3 of its sigmas. A sudden phase jump is not looked for. Only then is the frequency
   a window parameter (the data need it): the windows are refitted at their local frequency
   f_g + (c1 + 2 c2 (t_c - t_mean)) / (2 pi), with its std from the quadratic's covariance.
3. **Amplitude.** The largest step of the window amplitudes: for every split j (at least
   :data:`MIN_SIDE` windows either side) the weighted means before and after, z_j = delta_j / sd(delta_j); the
   best split's |z| is tested two-sided with Bonferroni over the splits (``ALPHA``), the windows' sigmas
   inflated by the Birge ratio sqrt(chi^2 / dof) of the two-level model when it exceeds 1 (correlated DIC
   noise makes the per-window sigmas optimistic). The amplitude has *changed* when that is significant AND
   |delta| exceeds :data:`AMPLITUDE_FLOOR` (0.5 %) of the global amplitude. The size of the change is then
   re-measured without the windows next to the split (the transition itself: a ramp shorter than a window),
   and its time from the transition window's level: a step at t_s inside a window of length L leaves it the
   fraction x = (t_to - t_s) / L of the way from the level before to the level after.

The drive is *stationary* when neither moved: the global sine stays the structure model (identical numbers:
nothing here changes the ``structure`` section). Otherwise results.json ``drive`` says what moved, by how much
and when, and a warning says so (:meth:`DriveModel.warning`). Fewer than :data:`MIN_WINDOWS` windows: not
tested (``stationary`` None). Units: mm, s, rad, Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vibro_model.codec import json_number as _num
from vibro_model.tail_probability import f_sf

from .structure_fit import StructureFit

WINDOW_CYCLES = 4            # drive cycles per window
WINDOW_HARMONICS = (2, 3)    # fitted beside the drive in each window (a drive's own distortion is not noise)
MIN_WINDOWS = 6              # fewer windows: not tested
MIN_SIDE = 2                 # a step leaves at least this many windows on each side
MIN_FILL = 0.5               # a window needs this share of its frames (lost frames)
ALPHA = 1e-3                 # family-wise false-alarm probability of each test (as the discrepancy analysis)
AMPLITUDE_FLOOR = 0.005      # physical floor: an amplitude change below 0.5 % is not reported
PHASE_FLOOR_RAD = 0.005      # physical floor: a phase excursion below 5 mrad is not reported


@dataclass(frozen=True, kw_only=True)
class DriveWindow:
    """One window's fit (mm, rad about t = 0 at the global frequency, Hz)."""

    t_s: float
    t_from_s: float
    t_to_s: float
    n_points: int
    amplitude_mm: float
    amplitude_std_mm: float
    phase_rad: float
    phase_std_rad: float
    offset_mm: float
    offset_std_mm: float
    frequency_hz: float
    frequency_std_hz: float | None   # None: the global frequency (the phase did not move)

    def to_dict(self) -> dict:
        return {k: (_num(v) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True, kw_only=True)
class AmplitudeChange:
    """The largest step of the window amplitudes (module docstring, 3)."""

    changed: bool
    change_mm: float
    change_std_mm: float
    before_mm: float
    after_mm: float
    t_s: float                   # when (the transition's time)
    t_between_s: tuple[float, float]   # the transition window's span
    z: float
    p_value: float               # Bonferroni over the splits
    birge: float

    @property
    def ratio(self) -> float:
        return self.change_mm / self.before_mm if self.before_mm > 0 else math.nan

    def to_dict(self) -> dict:
        ratio_std = self.change_std_mm / self.before_mm if self.before_mm > 0 else math.nan
        return {"changed": self.changed, "change_mm": _num(self.change_mm), "change_std_mm": _num(self.change_std_mm),
                "change_ratio": _num(self.ratio), "change_ratio_std": _num(ratio_std),
                "before_mm": _num(self.before_mm), "after_mm": _num(self.after_mm), "t_s": _num(self.t_s),
                "t_between_s": [_num(x) for x in self.t_between_s], "z": _num(self.z),
                "p_value": _num(self.p_value), "birge_ratio": _num(self.birge)}


@dataclass(frozen=True, kw_only=True)
class PhaseChange:
    """The quadratic of the window phases (module docstring, 2)."""

    moved: bool
    span_rad: float              # max - min of the curvature's phase about its best line over the take
    span_std_rad: float
    drift_hz_per_s: float
    drift_std_hz_per_s: float
    frequency_from_hz: float     # the frequency at the first and last window (Hz)
    frequency_to_hz: float
    t_max_rate_s: float          # where the phase moves fastest against the global sine (an end of the take)
    f_statistic: float
    p_value: float

    def to_dict(self) -> dict:
        return {"moved": self.moved, "span_rad": _num(self.span_rad), "span_std_rad": _num(self.span_std_rad),
                "frequency_drift_hz_per_s": _num(self.drift_hz_per_s),
                "frequency_drift_std_hz_per_s": _num(self.drift_std_hz_per_s),
                "frequency_from_hz": _num(self.frequency_from_hz), "frequency_to_hz": _num(self.frequency_to_hz),
                "t_max_rate_s": _num(self.t_max_rate_s), "f_statistic": _num(self.f_statistic),
                "p_value": _num(self.p_value)}


@dataclass(frozen=True, kw_only=True)
class DriveModel:
    """The windowed drive and the verdict (``stationary`` None: not tested, ``reason`` says why)."""

    stationary: bool | None
    window_s: float
    frequency_hz: float          # the global fit's (Hz)
    amplitude_mm: float          # the global fit's (mm)
    phase_rad: float             # the global fit's (rad, about t = 0)
    windows: list[DriveWindow] = field(default_factory=list)
    amplitude: AmplitudeChange | None = None
    phase: PhaseChange | None = None
    reason: str = ""

    def words(self) -> str:
        """What moved, by how much and when (empty when stationary or not tested)."""
        if self.stationary is not False:
            return ""
        parts = []
        a, p = self.amplitude, self.phase
        if a is not None and a.changed:
            parts.append(f"its amplitude changed by {100 * a.ratio:+.1f} % ({1e3 * a.change_mm:+.0f} um, "
                         f"{a.before_mm:.3f} -> {a.after_mm:.3f} mm) at t = {a.t_s:.2f} s")
        if p is not None and p.moved:
            parts.append(f"its phase moved by {1e3 * p.span_rad:.0f} mrad over the take (frequency drift "
                         f"{p.drift_hz_per_s:+.3g} Hz/s: {p.frequency_from_hz:.4f} -> {p.frequency_to_hz:.4f} Hz)")
        return "the drive is not stationary: " + " and ".join(parts)

    def warning(self) -> str | None:
        """The identification's warning for a drive that is not stationary, else None."""
        if self.stationary is not False:
            return None
        return (f"{self.words()}; the structure section's sine is the drive's average over the take (results.json "
                "drive: the windowed drive)")

    def to_dict(self) -> dict:
        return {"stationary": self.stationary, "tested": self.stationary is not None, "reason": self.reason,
                "words": self.words(), "window_s": _num(self.window_s), "window_cycles": WINDOW_CYCLES,
                "global": {"amplitude_mm": _num(self.amplitude_mm), "frequency_hz": _num(self.frequency_hz),
                           "phase_rad": _num(self.phase_rad)},
                "floors": {"alpha": ALPHA, "amplitude_ratio": AMPLITUDE_FLOOR, "phase_rad": PHASE_FLOOR_RAD},
                "amplitude": self.amplitude.to_dict() if self.amplitude is not None else None,
                "phase": self.phase.to_dict() if self.phase is not None else None,
                "windows": [w.to_dict() for w in self.windows]}


# ---------------------------------------------------------------- windows
def _window_fit(t: np.ndarray, y: np.ndarray, t_c: float, f_hz: float):
    """(amplitude, psi about t_c, offset) and their stds of a sine at ``f_hz`` (linear least squares), or None."""
    w = 2.0 * math.pi * f_hz
    cols = [np.sin(w * (t - t_c)), np.cos(w * (t - t_c)), np.ones_like(t)]
    for k in WINDOW_HARMONICS:
        cols += [np.sin(k * w * (t - t_c)), np.cos(k * w * (t - t_c))]
    X = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ coef
    try:
        cov = float(r @ r) / max(t.size - X.shape[1], 1) * np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        return None
    a, b, c = (float(v) for v in coef[:3])
    A = math.hypot(a, b)
    if A <= 0:
        return None
    gA = np.array([a, b]) / A
    gp = np.array([-b, a]) / A ** 2
    sub = cov[:2, :2]
    return (A, math.atan2(b, a), c, math.sqrt(max(float(gA @ sub @ gA), 0.0)),
            math.sqrt(max(float(gp @ sub @ gp), 0.0)), math.sqrt(max(float(cov[2, 2]), 0.0)))


def _windows(t: np.ndarray, y: np.ndarray, g: StructureFit, local_hz=None, local_std=None) -> list[DriveWindow]:
    """The windows' fits (module docstring, 1); ``local_hz(t_c)``: the local frequency when the phase moved."""
    L = WINDOW_CYCLES / g.frequency_hz
    period = 1.0 / float(np.median(np.diff(t)))
    edges = np.arange(t[0], t[-1] + 1e-12, L)
    out: list[DriveWindow] = []
    phi_prev = g.phase_rad
    for t0 in edges:
        sel = (t >= t0) & (t < t0 + L)
        if sel.sum() < max(10, MIN_FILL * L * period):
            continue
        tc = t0 + 0.5 * L
        f = float(local_hz(tc)) if local_hz is not None else g.frequency_hz
        fit = _window_fit(t[sel], y[sel], tc, f)
        if fit is None:
            continue
        A, psi, c, sA, sp, sc = fit
        # the phase a sine at the global frequency needs here (with a local frequency: its phase at t_c)
        phi = psi - 2.0 * math.pi * g.frequency_hz * tc
        phi = phi_prev + (phi - phi_prev + math.pi) % (2.0 * math.pi) - math.pi   # unwrapped along the take
        phi_prev = phi
        out.append(DriveWindow(t_s=tc, t_from_s=float(t0), t_to_s=float(t0 + L), n_points=int(sel.sum()),
                               amplitude_mm=A, amplitude_std_mm=sA, phase_rad=phi, phase_std_rad=sp, offset_mm=c,
                               offset_std_mm=sc, frequency_hz=f,
                               frequency_std_hz=float(local_std(tc)) if local_std is not None else None))
    return out


# ---------------------------------------------------------------- phase
def _phase_test(win: list[DriveWindow], g: StructureFit) -> tuple[PhaseChange, np.ndarray, np.ndarray, float]:
    """The weighted quadratic of the window phases (module docstring, 2): (verdict, coefficients about the mean
    window time, their covariance, that mean time). A line in the phases is a constant frequency a little off the
    global fit's (a stationary drive): only the curvature, a drifting frequency, is tested and measured."""
    t = np.array([w.t_s for w in win])
    d = np.array([w.phase_rad for w in win]) - g.phase_rad
    s = np.array([w.phase_std_rad for w in win])
    wts = 1.0 / np.maximum(s, 1e-12) ** 2
    tm = float(np.average(t, weights=wts))
    X = np.column_stack([np.ones_like(t), t - tm, (t - tm) ** 2])
    sw = np.sqrt(wts)
    coef, *_ = np.linalg.lstsq(X * sw[:, None], d * sw, rcond=None)
    chi_q = float((((d - X @ coef) * sw) ** 2).sum())
    lin, *_ = np.linalg.lstsq(X[:, :2] * sw[:, None], d * sw, rcond=None)
    chi_l = float((((d - X[:, :2] @ lin) * sw) ** 2).sum())
    dof = max(t.size - 3, 1)
    F = (chi_l - chi_q) / (chi_q / dof) if chi_q > 0 else math.inf
    p = f_sf(F, 1, dof) if math.isfinite(F) else 0.0
    cov = np.linalg.inv((X * wts[:, None]).T @ X) * max(1.0, chi_q / dof)
    # the excursion no single sine follows: the curvature's part of the phase, less its best line over the take
    grid = np.linspace(t[0], t[-1], 201)
    curve = (grid - tm) ** 2
    curve = curve - np.polyval(np.polyfit(grid, curve, 1), grid)
    unit_span = float(curve.max() - curve.min())
    span = abs(float(coef[2])) * unit_span
    span_std = math.sqrt(max(float(cov[2, 2]), 0.0)) * unit_span
    rate = np.abs(coef[1] + 2.0 * coef[2] * (grid - tm))
    moved = bool(p < ALPHA and span > PHASE_FLOOR_RAD and span > 3.0 * span_std)
    f_at = g.frequency_hz + (coef[1] + 2.0 * coef[2] * (np.array([t[0], t[-1]]) - tm)) / (2.0 * math.pi)
    return (PhaseChange(moved=moved, span_rad=span, span_std_rad=span_std, drift_hz_per_s=float(coef[2] / math.pi),
                        drift_std_hz_per_s=math.sqrt(max(float(cov[2, 2]), 0.0)) / math.pi,
                        frequency_from_hz=float(f_at[0]), frequency_to_hz=float(f_at[1]),
                        t_max_rate_s=float(grid[int(np.argmax(rate))]), f_statistic=float(F), p_value=float(p)),
            coef, cov, tm)


# ---------------------------------------------------------------- amplitude
def _weighted(x: np.ndarray, s: np.ndarray) -> tuple[float, float]:
    w = 1.0 / np.maximum(s, 1e-12) ** 2
    return float((w * x).sum() / w.sum()), float(1.0 / math.sqrt(w.sum()))


def _best_split(A: np.ndarray, s: np.ndarray) -> tuple[int, float]:
    """(split j, z) of the largest |z| of a step between windows j - 1 and j."""
    best = (MIN_SIDE, 0.0)
    for j in range(MIN_SIDE, A.size - MIN_SIDE + 1):
        m0, s0 = _weighted(A[:j], s[:j])
        m1, s1 = _weighted(A[j:], s[j:])
        z = (m1 - m0) / math.hypot(s0, s1)
        if abs(z) > abs(best[1]):
            best = (j, z)
    return best


def _amplitude_test(win: list[DriveWindow], g: StructureFit) -> AmplitudeChange:
    """The largest amplitude step (module docstring, 3)."""
    from scipy.special import ndtr

    A = np.array([w.amplitude_mm for w in win])
    s = np.array([w.amplitude_std_mm for w in win])
    j, z = _best_split(A, s)
    m0, _ = _weighted(A[:j], s[:j])
    m1, _ = _weighted(A[j:], s[j:])
    model = np.where(np.arange(A.size) < j, m0, m1)
    birge = max(1.0, math.sqrt(float((((A - model) / s) ** 2).sum()) / max(A.size - 2, 1)))
    z /= birge
    n_splits = max(A.size - 2 * MIN_SIDE + 1, 1)
    p = min(1.0, 2.0 * float(ndtr(-abs(z))) * n_splits)
    # the size without the transition: one window left out on each side of the split (when enough remain)
    lo, hi = (j - 1, j + 1) if j - 1 >= 1 and A.size - (j + 1) >= 1 else (j, j)
    b0, e0 = _weighted(A[:lo], s[:lo] * birge)
    b1, e1 = _weighted(A[hi:], s[hi:] * birge)
    delta, sd = b1 - b0, math.hypot(e0, e1)
    k = _transition(A, j, b0, b1)
    x = min(1.0, max(0.0, (A[k] - b0) / delta)) if delta != 0 else 0.5
    w = win[k]
    t_step = w.t_to_s - x * (w.t_to_s - w.t_from_s)
    changed = bool(p < ALPHA and abs(delta) > AMPLITUDE_FLOOR * g.amplitude_mm)
    return AmplitudeChange(changed=changed, change_mm=delta, change_std_mm=sd, before_mm=b0, after_mm=b1,
                           t_s=float(t_step), t_between_s=(w.t_from_s, w.t_to_s), z=float(z), p_value=p,
                           birge=birge)


def _transition(A: np.ndarray, j: int, b0: float, b1: float) -> int:
    """The window next to split ``j`` whose amplitude is nearest the middle of the two levels."""
    mid = 0.5 * (b0 + b1)
    cands = [k for k in (j - 1, j) if 0 <= k < A.size]
    return min(cands, key=lambda k: abs(A[k] - mid))


# ---------------------------------------------------------------- the model
def fit_drive(t_s: np.ndarray, y_mm: np.ndarray, structure: StructureFit, moving: bool = True) -> DriveModel | None:
    """The windowed drive of the structure track ``y_mm`` (mm) at ``t_s`` (s) and its verdict against the global
    sine ``structure`` (module docstring); None when the structure does not move (no drive to follow)."""
    if not moving or not math.isfinite(structure.frequency_hz) or structure.frequency_hz <= 0:
        return None
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(y_mm, dtype=float)
    ok = np.isfinite(t) & np.isfinite(y)
    t, y = t[ok], y[ok]
    L = WINDOW_CYCLES / structure.frequency_hz
    base = {"window_s": L, "frequency_hz": structure.frequency_hz, "amplitude_mm": structure.amplitude_mm,
            "phase_rad": structure.phase_rad}
    win = _windows(t, y, structure) if t.size > 10 else []
    if len(win) < MIN_WINDOWS:
        return DriveModel(stationary=None, windows=win, reason=(
            f"{len(win)} windows of {WINDOW_CYCLES} drive cycles ({L:.3f} s), the test needs {MIN_WINDOWS}"), **base)
    phase, coef, cov, tm = _phase_test(win, structure)
    if phase.moved:
        def local_hz(tc: float) -> float:
            return structure.frequency_hz + (coef[1] + 2.0 * coef[2] * (tc - tm)) / (2.0 * math.pi)

        def local_std(tc: float) -> float:
            gv = np.array([0.0, 1.0, 2.0 * (tc - tm)]) / (2.0 * math.pi)
            return math.sqrt(max(float(gv @ cov @ gv), 0.0))

        win = _windows(t, y, structure, local_hz, local_std)
    amplitude = _amplitude_test(win, structure)
    stationary = not (amplitude.changed or phase.moved)
    return DriveModel(stationary=stationary, windows=win, amplitude=amplitude, phase=phase, **base)
