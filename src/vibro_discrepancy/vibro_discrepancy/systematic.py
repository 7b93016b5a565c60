"""Systematic mismatch the final model leaves, separated from random scatter.

Three series of the final model's residuals are tested for a pattern, each with its own noise:

- the structure track (every frame; noise sigma_s from 5th differences of the track, known): drive
  harmonics 1..5 are fitted first (the baseline's sine and the catalogue's ``structure_harmonics`` are
  drive-locked), then a trend in time, a step, and a tone at any other frequency (least-squares
  periodogram);
- each plate's contact level: the ball's position relative to the measured structure at each impact,
  y_flight(t_i) - Y_s,measured(t_i) (the model's flights, whose meeting point is the impact time, and the
  structure track, so a structure-model error does not leak in): the plate's height in the structure's
  frame. Tested for a trend or a step in time (noise estimated from the series: F-tests);
- the COR residual of the final COR law (the per-impact CORs scatter physically: the noise is that
  scatter, estimated: F-tests): trend and step in time, slope with impact speed within each plate, a
  difference between the plates, slope with the drive phase of the impact within each plate, and the
  impact's parity on each plate (the COR alternating on the plate's successive impacts: :func:`parity_signs`).
  These are the coordinates of the catalogue's COR laws (plate, speed) and those next to them (time,
  phase, parity): a COR pattern left after a chosen COR law means the law does not fit the COR's shape.

Matching pursuit per series: the strongest pattern is accepted when its family-corrected p-value
(Bonferroni over its candidate split points or frequencies, and over every test of the recording:
``ALPHA_FAMILY``) is small AND it is large enough to matter (``MIN_*``: the floors the catalogue's
selection uses, so a pattern too small for a catalogue term is too small here); then it is subtracted
and the next strongest is tested (at most ``MAX_COMPONENTS``). What is left of the COR residual after
the accepted COR patterns is the random contact scatter (:func:`contact_scatter`).

A drive that did not hold still (the identification's results.json ``drive``: ``stationary`` false,
:func:`vibro_discrepancy.data.drive_change`) leaves side bands around the drive frequency in the residual of any
stationary structure model: the structure's periodic patterns within the windowed drive model's bandwidth of a
drive harmonic (+-1 / window: what the windows can follow) are the drive changing, not tones. They are replaced by
one ``drive`` pattern that says what the drive did (:func:`drive_patterns`); a tone outside that band is still one.
The COR patterns are then sought in CORs with the structure velocity the identification measured at each impact
(its local fit follows the drive: :func:`drive_following_cor`), not the stationary sine's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vibro_discrepancy.data import Measured, drive_change, drive_change_words
from vibro_discrepancy.fitting import ImpactSet, fit_cor
from vibro_discrepancy.model import COR_TERMS, FittedModel
from vibro_model.codec import json_number as _num
from vibro_model.tail_probability import chi2_sf, f_sf

ALPHA_FAMILY = 1e-3          # family-wise false-alarm probability over all tests of one recording
N_SERIES = 4                 # structure, two contact levels, COR: ALPHA_FAMILY is split among them
MIN_STRUCTURE_SIGMA = 3.0    # structure pattern: amplitude / change >= this x sigma_s (as harmonics)
MIN_LEVEL_SIGMA = 4.0        # contact level change >= this x the ball's per-frame noise floor
MIN_COR_RMS = 0.004          # COR pattern: RMS of what it explains (as select.MIN_COR_RMS)
MAX_COMPONENTS = 3
DRIVE_HARMONICS = 5
MIN_SPLIT = 3                # a step leaves at least this many samples (levels, CORs) on each side
MIN_SPLIT_FRAMES = 10        # ... frames (structure)
OVERSAMPLE = 4               # periodogram grid: 1 / (OVERSAMPLE T)
PERIODOGRAM_BLOCK = 1 << 20  # direct tone sums: frequencies x samples computed at a time (8 MiB a float64 array)
TAYLOR_TOL = 1e-15           # FFT periodogram: the off-clock series stops below this (relative to sum |w|)
MAX_TAYLOR_PHASE = 2 * math.pi   # ... used while 2 pi f (time - clock) stays below this (rad; at most ~45 terms)


@dataclass(kw_only=True)
class Mismatch:
    """One systematic pattern: which series (and plate), its shape, size and significance."""

    series: str                 # "structure", "contact_level", "cor"
    shape: str                  # "trend", "step", "periodic", "speed", "plate", "phase", "parity"
    size: float                 # trend/step: change over the span / the jump; periodic: amplitude;
                                # speed/phase: change over the range; plate: top - bottom; parity: the
                                # even impacts' COR - the odd ones' (unit below)
    unit: str                   # "um" or "cor"
    t_from_s: float
    t_to_s: float
    p_value: float              # family-corrected
    statistic: float
    plate: str | None = None
    frequency_hz: float | None = None
    step_time_s: float | None = None
    step_between_s: tuple[float, float] | None = None   # the samples either side of the step (s)
    size_ms: float | None = None   # contact level: the impact-time shift it causes (ms)
    frequencies_searched: int | None = None   # periodic: independent frequencies the search tried
    levels: tuple[float, float] | None = None   # parity: the mean measured COR on the even and odd impacts
    note: str | None = None        # drive: what the drive did (results.json drive's words)
    absorbed_hz: tuple[float, ...] | None = None   # drive: the side-band "tones" it stands for (Hz)
    fit: np.ndarray | None = None  # the pattern's values on the series (for subtraction)
    common_mode: bool = False      # contact level: the other plate's level does the same (:func:`common_mode_levels`)

    def what(self) -> str:
        """Plain words: where, shape, size and when."""
        where = {"structure": "structure", "contact_level": f"{self.plate} plate height",
                 "cor": "COR" + (f" ({self.plate} plate)" if self.plate else "")}[self.series]
        u = " um" if self.unit == "um" else ""
        span = f"t = {self.t_from_s:.3f} to {self.t_to_s:.3f} s"
        ms = f" (impact times shift by {self.size_ms:.3f} ms)" if self.size_ms is not None else ""
        if self.shape == "drive":
            tones = ", ".join(f"{f:.2f}" for f in self.absorbed_hz or ())
            return (f"structure: {self.note}: not a structure tone (the side bands at {tones} Hz) and not ball "
                    "physics: the drive changed (results.json drive)")
        if self.shape == "trend":
            what = f"drifts by {self.size:+.3g}{u} over {span}{ms}"
        elif self.shape == "step":
            between = (f" (between the impacts at {self.step_between_s[0]:.3f} and {self.step_between_s[1]:.3f} s)"
                       if self.step_between_s is not None and self.series != "structure" else "")
            what = f"steps by {self.size:+.3g}{u} at t = {self.step_time_s:.3f} s{between}{ms}"
        elif self.shape == "periodic":
            what = (f"oscillates at {self.frequency_hz:.2f} Hz (not a drive harmonic) with amplitude "
                    f"{self.size:.3g}{u} over {span}")
        elif self.shape == "plate":
            what = f"differs between the plates by {self.size:+.3g} (top - bottom)"
        elif self.shape == "parity":
            pl = {"top": "upper", "bottom": "lower"}.get(self.plate or "", "")
            between = (f"between {self.levels[0]:.3f} and {self.levels[1]:.3f}" if self.levels is not None
                       else f"by {self.size:+.3g}")
            return f"COR alternates {between} on successive {pl}-plate impacts (t = {self.t_from_s:.3f} to " \
                   f"{self.t_to_s:.3f} s)"
        else:
            what = f"changes by {self.size:+.3g} over the range of impact {self.shape}s within each plate"
        return f"{where}: {what}"

    def words(self) -> str:
        p = f"p = {self.p_value:.1e}" if self.p_value > 1e-300 else "p < 1e-300"
        if self.common_mode:
            return (f"{self.what()}, {p}, and the other plate's height does the same: the ball's or the structure's "
                    "track moved (a spinning ball's rotation leaks into its track), or the whole cavity against the "
                    "tracked structure; no plate moved against the other, no finding")
        if self.shape == "drive":
            return f"{self.what()}; the catalogue's structure models assume a stationary drive (paper Eq. 2)"
        return f"{self.what()}, {p}, which no term of the library produces"

    def to_dict(self) -> dict:
        out = {"series": self.series, "shape": self.shape, "plate": self.plate, "size": _num(self.size),
               "unit": self.unit, "t_from_s": _num(self.t_from_s), "t_to_s": _num(self.t_to_s),
               "p_value": _num(self.p_value), "statistic": _num(self.statistic), "words": self.words()}
        if self.frequency_hz is not None:
            out["frequency_hz"] = _num(self.frequency_hz)
        if self.step_time_s is not None:
            out["step_time_s"] = _num(self.step_time_s)
        if self.step_between_s is not None:
            out["step_between_s"] = [_num(x) for x in self.step_between_s]
        if self.size_ms is not None:
            out["size_ms"] = _num(self.size_ms)
        if self.common_mode:
            out["common_mode"] = True
        if self.frequencies_searched is not None:
            out["frequencies_searched"] = int(self.frequencies_searched)
        if self.levels is not None:
            out["levels"] = [_num(x) for x in self.levels]
        if self.absorbed_hz is not None:
            out["absorbed_tones_hz"] = [_num(x) for x in self.absorbed_hz]
        return out


# --- candidate patterns: (drop of the sum of squares, fitted values, description) -------------------

def _centre(x: np.ndarray) -> np.ndarray:
    return x - x.mean()


def _trend(t: np.ndarray, r: np.ndarray):
    x = _centre(t)
    xx = float(x @ x)
    if xx <= 0:
        return None
    c = float(x @ r) / xx
    return c * c * xx, c * x, {"size": c * (t.max() - t.min())}, 1


def _step(t: np.ndarray, r: np.ndarray, min_side: int):
    """Best single step (r centred): drop n S_k^2 / (k (n - k)) with S_k the sum after the split."""
    n = r.size
    if n < 2 * min_side:
        return None
    order = np.argsort(t)
    t, r = t[order], r[order]
    tail = np.cumsum(r[::-1])[::-1]          # tail[k] = sum_{i >= k} r_i
    k = np.arange(min_side, n - min_side + 1)
    drop = tail[k] ** 2 * n / (k * (n - k))
    j = int(np.argmax(drop))
    kk = int(k[j])
    jump = tail[kk] * n / (kk * (n - kk))
    fit = np.where(np.arange(n) >= kk, jump * kk / n, -jump * (n - kk) / n)
    out = np.empty_like(fit)
    out[order] = fit
    return float(drop[j]), out, {"size": float(jump), "step_time_s": 0.5 * float(t[kk - 1] + t[kk]),
                                 "step_between_s": (float(t[kk - 1]), float(t[kk]))}, k.size


def _centred_columns(t: np.ndarray, freqs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cosine and sine of 2 pi f t, one row per frequency, each row centred (its mean removed)."""
    ph = 2 * np.pi * np.outer(freqs, t)
    C, S = np.cos(ph), np.sin(ph)
    C -= C.mean(axis=1, keepdims=True)
    S -= S.mean(axis=1, keepdims=True)
    return C, S


def _fit_drop(cc, ss, cs, cr, sr):
    """Least squares of r on a centred cosine and sine from their Gram sums: (drop of the sum of squares, a, b)."""
    det = cc * ss - cs ** 2
    a = (ss * cr - cs * sr) / det
    b = (cc * sr - cs * cr) / det
    return a * cr + b * sr, a, b


def tone_drops_direct(t: np.ndarray, r: np.ndarray, freqs: np.ndarray, block: int = PERIODOGRAM_BLOCK
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(drop, a, b) of the least-squares tone fit ``a C + b S`` (centred cos and sin columns) at each of
    ``freqs``, by the direct sums over the samples, ``block`` (frequencies x samples) values at a time:
    the memory is O(block + samples) whatever the number of frequencies (each row is computed alone, so
    the blocks give the numbers of one whole matrix). O(frequencies x samples) time: for a short list."""
    t = np.asarray(t, dtype=float)
    r = np.asarray(r, dtype=float)
    freqs = np.asarray(freqs, dtype=float)
    out = np.empty((3, freqs.size))
    rows = max(1, int(block) // max(t.size, 1))
    for i in range(0, freqs.size, rows):
        C, S = _centred_columns(t, freqs[i:i + rows])
        out[:, i:i + rows] = _fit_drop((C * C).sum(1), (S * S).sum(1), (C * S).sum(1), C @ r, S @ r)
    return out[0], out[1], out[2]


def _fourier_sums(tau: np.ndarray, w: np.ndarray, f0: float, n_grid: int, h: float, m_fft: int, n_freqs: int,
                  tol: float = TAYLOR_TOL) -> np.ndarray | None:
    """sum_k w_k exp(-2 pi i f_j tau_k) at f_j = f0 + j / (m_fft h), j < ``n_freqs``, for each row of the
    weights ``w`` (rows x samples): exact to ``tol`` relative to sum |w|, in O(m_fft log m_fft) per term.

    Each time is a point of the grid n h plus an offset: tau_k = n_k h + d_k (``n_grid`` = n_k, |d_k| <= h/2).
    Then exp(-2 pi i f_j tau_k) = exp(-2 pi i f0 n_k h) exp(-2 pi i j n_k / m_fft) exp(-2 pi i f_j d_k): the
    middle factor is a DFT of length ``m_fft`` over n (exact for any n, the exponential being periodic in
    n and j), the first a weight, the last a Taylor series sum_p (-2 pi i f_j)^p d_k^p / p!, one FFT per
    power of d (Anderson and Dahleh 1996); the series stops when its next term is below ``tol``. On an
    exact frame clock d = 0 and one FFT is all. None when 2 pi f d exceeds ``MAX_TAYLOR_PHASE`` (times
    that are not near a clock of step h)."""
    d = tau - n_grid * h
    f_max = max(abs(f0), abs(f0 + (n_freqs - 1) / (m_fft * h)))
    x = 2 * np.pi * f_max * float(np.max(np.abs(d), initial=0.0))
    if not x <= MAX_TAYLOR_PHASE:
        return None
    base = w * np.exp(-2j * np.pi * f0 * h * n_grid)
    bins = np.mod(n_grid, m_fft)
    j = np.arange(n_freqs)
    fj = f0 + j / (m_fft * h)
    total = np.zeros((w.shape[0], n_freqs), dtype=complex)
    coef = np.ones(n_freqs, dtype=complex)
    term_bound, p = 1.0, 0
    dp = np.ones_like(d)
    while True:
        for row in range(w.shape[0]):
            grid = (np.bincount(bins, (base[row] * dp).real, minlength=m_fft)
                    + 1j * np.bincount(bins, (base[row] * dp).imag, minlength=m_fft))
            total[row] += coef * np.fft.fft(grid)[np.mod(j, m_fft)]
        p += 1
        term_bound *= x / p
        if term_bound < tol:
            return total
        dp = dp * d
        coef = coef * (-2j * np.pi * fj) / p


def tone_drops_grid(t: np.ndarray, r: np.ndarray, f_lo: float, step: float, n_freqs: int) -> np.ndarray:
    """The drop of :func:`tone_drops_direct` at the grid f_lo + j ``step`` (j < ``n_freqs``, ``step`` = 1 /
    (OVERSAMPLE T) for the search) from Fourier sums by FFT (:func:`_fourier_sums`): the same numbers to
    float rounding, in O(samples) memory and O(samples log samples) time (the direct sums are frequencies
    x samples: quadratic in the recording's length). Any sampling: the times are put on the nearest
    frame of a clock whose span is a whole number of median frame intervals; the offsets enter exactly
    through their Taylor series."""
    t = np.asarray(t, dtype=float)
    r = np.asarray(r, dtype=float)
    n = t.size
    tau = t - t.min()
    T = float(tau.max())
    dt = float(np.median(np.diff(np.sort(t))))
    n_span = max(1, int(round(T / dt))) if dt > 0 else 1
    h = T / n_span
    grid_n = np.rint(tau / h).astype(np.int64)
    m1 = max(1, int(round(1.0 / (step * h))))
    if abs(m1 * step * h - 1.0) > 1e-9:   # a step that is not a whole fraction of the clock: direct sums
        return tone_drops_direct(t, r, f_lo + step * np.arange(n_freqs))[0]
    one = np.ones((1, n))
    first = _fourier_sums(tau, np.vstack([one[0], r]), f_lo, grid_n, h, m1, n_freqs)
    if m1 % 2 == 0:
        second = _fourier_sums(tau, one, 2 * f_lo, grid_n, h, m1 // 2, n_freqs)
    else:
        second = _fourier_sums(tau, one, 2 * f_lo, grid_n, h, m1, 2 * n_freqs)
        second = None if second is None else second[:, ::2]
    if first is None or second is None:   # times far from any clock: the direct sums
        return tone_drops_direct(t, r, f_lo + step * np.arange(n_freqs))[0]
    second = second[0]
    cs1, ss1 = first[0].real, -first[0].imag          # sum cos, sum sin
    rc, rs = first[1].real, -first[1].imag            # sum r cos, sum r sin
    c2, s2 = second.real, -second.imag                # sum cos 2w t, sum sin 2w t
    r_sum = float(r.sum())
    cc = 0.5 * (n + c2) - cs1 * cs1 / n
    ss = 0.5 * (n - c2) - ss1 * ss1 / n
    cs = 0.5 * s2 - cs1 * ss1 / n
    drop, _, _ = _fit_drop(cc, ss, cs, rc - cs1 * r_sum / n, rs - ss1 * r_sum / n)
    return drop


def _periodogram(t: np.ndarray, r: np.ndarray, f_lo: float, f_hi: float, exclude_hz: list[float], width_hz: float):
    """Best tone by least squares over a grid (centred sin and cos columns): (drop, fit, info, trials).

    The grid (step 1 / (OVERSAMPLE T)) by FFT (:func:`tone_drops_grid`), then 41 frequencies within one
    step of its best by the direct sums (:func:`tone_drops_direct`): memory linear in the samples."""
    T = float(t.max() - t.min())
    if T <= 0 or f_hi <= f_lo:
        return None
    step = 1.0 / (OVERSAMPLE * T)
    grid = np.arange(f_lo, f_hi, step)
    keep = np.ones(grid.size, bool)
    for f in exclude_hz:
        keep &= np.abs(grid - f) > width_hz
    if not keep.any():
        return None
    d = tone_drops_grid(t, r, f_lo, step, grid.size)
    d[~keep] = np.nan
    j = int(np.nanargmax(d))
    fine = np.linspace(grid[j] - step, grid[j] + step, 41)
    d2, a, b = tone_drops_direct(t, r, fine)
    m = int(np.nanargmax(d2))
    C, S = _centred_columns(t, fine[m:m + 1])
    fit = a[m] * C[0] + b[m] * S[0]
    trials = max(1, int(round((f_hi - f_lo) * T)))   # independent frequencies in the band
    return float(d2[m]), fit, {"size": float(math.hypot(a[m], b[m])), "frequency_hz": float(fine[m])}, trials


def tone_search(t: np.ndarray, r: np.ndarray, f0_hz: float, fps: float):
    """The strongest tone of the residual ``r`` (m) in the structure analysis' band (1.5/T to fps/2, drive
    harmonics 1..DRIVE_HARMONICS +- 1/T left out): (drop of the sum of squares, fit, {"size",
    "frequency_hz"}, independent frequencies searched) or None."""
    T = float(t.max() - t.min())
    return _periodogram(t, r, 1.5 / T, 0.5 * fps, [k * f0_hz for k in range(1, DRIVE_HARMONICS + 1)], 1.0 / T)


def _p_known(drop: float, sigma: float, dof: int, trials: int, n_tests: int) -> tuple[float, float]:
    chi = drop / max(sigma, 1e-300) ** 2
    return chi, min(1.0, chi2_sf(chi, dof) * trials * n_tests)


def _p_estimated(drop: float, sse_after: float, dof: int, n: int, n_par: int, trials: int, n_tests: int
                 ) -> tuple[float, float]:
    den = n - n_par
    if den <= 0 or sse_after <= 0:
        return float("nan"), 1.0
    F = (drop / dof) / (sse_after / den)
    return F, min(1.0, f_sf(F, dof, den) * trials * n_tests)


# --- the three series -----------------------------------------------------------------------------

def _drive_columns(t: np.ndarray, f0: float) -> list[np.ndarray]:
    cols = [np.ones_like(t)]
    for k in range(1, DRIVE_HARMONICS + 1):
        cols += [np.sin(2 * np.pi * k * f0 * t), np.cos(2 * np.pi * k * f0 * t)]
    return cols


def _pattern_columns(t: np.ndarray, shape: str, info: dict) -> list[np.ndarray]:
    if shape == "trend":
        return [t - t.mean()]
    if shape == "step":
        return [(t > info["step_time_s"]).astype(float)]
    w = 2 * np.pi * info["frequency_hz"]
    return [np.sin(w * t), np.cos(w * t)]


def _joint_fit(t: np.ndarray, r0: np.ndarray, f0: float, accepted: list[tuple[str, dict]]):
    """Least squares of the drive harmonics and every accepted pattern together on the structure residual
    r0 (short records: a tone and the harmonics are not orthogonal, so each is refitted with the others).
    Returns (what is left, [(size, values) per accepted pattern])."""
    cols = _drive_columns(t, f0)
    spans = []
    for shape, info in accepted:
        pc = _pattern_columns(t, shape, info)
        spans.append((len(cols), len(cols) + len(pc)))
        cols += pc
    X = np.column_stack(cols)
    c, *_ = np.linalg.lstsq(X, r0, rcond=None)
    parts = []
    for (shape, _), (i, j) in zip(accepted, spans):
        vals = X[:, i:j] @ c[i:j]
        if shape == "trend":
            size = float(c[i]) * float(t[-1] - t[0])
        elif shape == "step":
            size = float(c[i])
        else:
            size = float(math.hypot(c[i], c[i + 1]))
        parts.append((size, vals))
    return r0 - X @ c, parts


def _refine(sse, x0: float, half_width: float) -> float:
    """1-D bounded minimisation of ``sse`` around x0 (kept if it does not improve)."""
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(sse, bounds=(x0 - half_width, x0 + half_width), method="bounded",
                          options={"xatol": 1e-4 * half_width})
    return float(res.x) if res.success and sse(res.x) <= sse(x0) else x0


def _refine_frequencies(t: np.ndarray, r0: np.ndarray, f0: float, accepted: list[tuple[str, dict]]) -> float:
    """Refine the drive frequency and each accepted tone's frequency (within 1/T) in the joint fit: a line
    at a slightly wrong frequency leaves side lobes that would pass for other tones. Returns the drive
    frequency; tone frequencies are updated in place."""
    T = float(t[-1] - t[0])

    def sse_drive(f):
        left, _ = _joint_fit(t, r0, f, accepted)
        return float(left @ left)

    f0 = _refine(sse_drive, f0, 1.0 / T)
    for shape, info in accepted:
        if shape != "periodic":
            continue

        def sse_tone(f, info=info):
            old = info["frequency_hz"]
            info["frequency_hz"] = f
            left, _ = _joint_fit(t, r0, f0, accepted)
            info["frequency_hz"] = old
            return float(left @ left)

        info["frequency_hz"] = _refine(sse_tone, info["frequency_hz"], 0.5 / T)
    return f0


def structure_mismatch(t: np.ndarray, structure_m: np.ndarray, sigma_m: float, f0_hz: float, fps: float,
                       n_tests: int = N_SERIES) -> list[Mismatch]:
    """Trend, step and tones in the structure track (m) beyond any drive-locked motion (harmonics 1..5 at
    the drive frequency refined on the track: every structure model of the library is one), sizes in um.
    Each accepted pattern is refitted jointly with the harmonics and the patterns before it."""
    r0 = np.asarray(structure_m, float)
    f0_hz = _refine_frequencies(t, r0, f0_hz, [])
    r, _ = _joint_fit(t, r0, f0_hz, [])
    accepted: list[tuple[str, dict, float, float, int]] = []
    for _ in range(MAX_COMPONENTS):
        cands = []
        for shape, c in (("trend", _trend(t, r)), ("step", _step(t, r - r.mean(), MIN_SPLIT_FRAMES)),
                         ("periodic", tone_search(t, r, f0_hz, fps))):
            if c is None:
                continue
            drop, fit, info, trials = c
            stat, p = _p_known(drop, sigma_m, 2 if shape == "periodic" else 1, trials, n_tests)
            cands.append((p, -drop, shape, fit, info, stat, trials))
        if not cands:
            break
        p, _, shape, fit, info, stat, trials = min(cands, key=lambda c: (c[0], c[1]))
        p = min(1.0, p * len(cands))   # Bonferroni over the shapes tried
        if p >= ALPHA_FAMILY or abs(info["size"]) < MIN_STRUCTURE_SIGMA * sigma_m:
            break
        accepted.append((shape, info, p, stat, trials))
        f0_hz = _refine_frequencies(t, r0, f0_hz, [(a[0], a[1]) for a in accepted])
        r, _ = _joint_fit(t, r0, f0_hz, [(a[0], a[1]) for a in accepted])
    _, parts = _joint_fit(t, r0, f0_hz, [(a[0], a[1]) for a in accepted])
    return [Mismatch(series="structure", shape=shape, size=size * 1e6, unit="um", t_from_s=float(t[0]),
                     t_to_s=float(t[-1]), p_value=p, statistic=stat, frequency_hz=info.get("frequency_hz"),
                     step_time_s=info.get("step_time_s"), fit=vals,
                     frequencies_searched=trials if shape == "periodic" else None)
            for (shape, info, p, stat, trials), (size, vals) in zip(accepted, parts)]


@dataclass(frozen=True)
class SeriesScale:
    """How a short series' patterns are judged and reported: ``floor`` the minimum size that matters (in the
    series' own unit: m, COR), of the fitted pattern's RMS when ``rms_floor`` else of its size; sizes are
    reported times ``unit_scale`` in ``unit``."""

    floor: float
    unit_scale: float
    unit: str
    rms_floor: bool


def _column_candidates(r: np.ndarray, columns: dict) -> list[tuple[str, tuple]]:
    """Each extra regressor {shape: x} projected on the series ``r``: (shape, (drop of the sum of squares, fitted
    values, {"size": change over x's range, or c for ``plate``}, 1 trial)); a zero column is left out."""
    out = []
    for shape, x in columns.items():
        xx = float(x @ x)
        if xx > 0:
            c = float(x @ r) / xx
            out.append((shape, (c * c * xx, c * x, {"size": c * (x.max() - x.min()) if shape != "plate"
                                                    else c}, 1)))
    return out


def _strongest_pattern(t: np.ndarray, r: np.ndarray, columns: dict, n_par: int, n_tests: int):
    """The pursuit's next pattern on the series ``r`` at times ``t`` (s): trend, step in time or an extra
    regressor of ``columns``, the one with the smallest p-value (F-test against the ``n_par`` parameters
    fitted so far; Bonferroni over the shapes tried); (p, shape, fitted values, info, statistic) or None."""
    cands = []
    gens = [("trend", _trend(t, r)), ("step", _step(t, r, MIN_SPLIT))] + _column_candidates(r, columns)
    for shape, c in gens:
        if c is None:
            continue
        drop, fit, info, trials = c
        sse_after = float(((r - fit) ** 2).sum())
        extra = 2 if shape == "step" else 1
        stat, p = _p_estimated(drop, sse_after, 1, r.size, n_par + extra, trials, n_tests)
        cands.append((p, -drop, shape, fit, info, stat))
    if not cands:
        return None
    p, _, shape, fit, info, stat = min(cands, key=lambda c: (c[0], c[1]))
    return min(1.0, p * len(cands)), shape, fit, info, stat


def _series_pursuit(series: str, t: np.ndarray, r: np.ndarray, columns: dict, scale: SeriesScale,
                    plate: str | None, n_tests: int) -> list[Mismatch]:
    """Matching pursuit on a short series with estimated noise (F-tests). ``columns``: extra regressors
    {shape: x} (already centred within groups) beside the trend and the step in time. ``scale``: the minimum
    size that matters and the reported unit (:class:`SeriesScale`)."""
    out: list[Mismatch] = []
    r = r - r.mean()
    n_par = 1
    for _ in range(MAX_COMPONENTS):
        best = _strongest_pattern(t, r, columns, n_par, n_tests)
        if best is None:
            break
        p, shape, fit, info, stat = best
        size = math.sqrt(float(np.mean(fit ** 2))) if scale.rms_floor else abs(info["size"])
        if not (p < ALPHA_FAMILY) or not size >= scale.floor:
            break
        out.append(Mismatch(series=series, shape=shape, size=info["size"] * scale.unit_scale, unit=scale.unit,
                            t_from_s=float(t.min()), t_to_s=float(t.max()), p_value=p, statistic=stat, plate=plate,
                            step_time_s=info.get("step_time_s"), step_between_s=info.get("step_between_s"), fit=fit))
        r = r - fit
        n_par += 2 if shape == "step" else 1
    return out


def contact_levels(meas: Measured, model: FittedModel) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """{plate: (impact times s, contact level m, relative impact speed m/s)}: the model flight's position
    at each impact minus the measured structure there (the structure model plus its interpolated
    residual, so structure-model errors cancel)."""
    S = model.motion
    r_s = meas.structure_m - np.asarray(S.position(meas.t_s), float)
    out: dict[str, list] = {"top": [], "bottom": []}
    imps = model.impacts
    for i, t, plate, spd in zip(imps.index, imps.t_s, imps.plate, imps.speed):
        imp = meas.impacts[int(i)]
        k = imp.flight_before if imp.flight_before is not None else imp.flight_after
        if k is None:
            continue
        y, _ = model.flights.state(k, t - meas.flights[k].t_ref_s)
        ys = float(S.position(t)) + float(np.interp(t, meas.t_s, r_s))
        out[plate].append((float(t), float(y) - ys, float(spd)))
    return {p: tuple(np.array(c) for c in zip(*v)) for p, v in out.items() if len(v) >= 2 * MIN_SPLIT}


def level_mismatch(meas: Measured, model: FittedModel, sigma_f_m: float, n_tests: int = N_SERIES
                   ) -> list[Mismatch]:
    """Trend or step of each plate's contact level in time (um; and the impact-time shift in ms)."""
    out = []
    for plate, (t, lvl, spd) in contact_levels(meas, model).items():
        scale = SeriesScale(floor=MIN_LEVEL_SIGMA * sigma_f_m, unit_scale=1e6, unit="um", rms_floor=False)
        found = _series_pursuit("contact_level", t, lvl, {}, scale, plate, n_tests)
        for m in found:
            m.size_ms = abs(m.size) * 1e-6 / max(float(np.median(spd)), 1e-6) * 1e3
        out += found
    return common_mode_levels(out, meas.frequency_hz)


#: two plates' level patterns are one common-mode pattern when their sizes differ by at most this fraction
COMMON_MODE_REL = 0.35


def common_mode_levels(patterns: list[Mismatch], frequency_hz: float) -> list[Mismatch]:
    """``patterns`` with each pair of a top and a bottom contact-level pattern that are one motion of both plates
    marked ``common_mode``: the same shape (a step within 1.5 drive periods of the other's, or a trend over
    overlapping spans) and sizes of one sign within :data:`COMMON_MODE_REL` of each other. A plate moving against the
    other changes its own level only; both levels moving alike is the ball's or the structure's track (a spinning
    ball's rotation leaks ~0.4 um per degree into its mesh's translation) or the cavity as a whole against the
    tracked structure, neither ball physics."""
    tops = [m for m in patterns if m.series == "contact_level" and m.plate == "top"]
    bottoms = [m for m in patterns if m.series == "contact_level" and m.plate == "bottom"]
    for a in tops:
        for b in bottoms:
            if a.common_mode or b.common_mode or a.shape != b.shape or a.shape not in ("step", "trend"):
                continue
            if a.size * b.size <= 0 or abs(a.size - b.size) > COMMON_MODE_REL * max(abs(a.size), abs(b.size)):
                continue
            if a.shape == "step":
                together = (a.step_time_s is not None and b.step_time_s is not None
                            and abs(a.step_time_s - b.step_time_s) <= 1.5 / max(frequency_hz, 1e-9))
            else:
                together = min(a.t_to_s, b.t_to_s) > max(a.t_from_s, b.t_from_s)
            if together:
                a.common_mode = b.common_mode = True
    return patterns


def _within(x: np.ndarray, plates: np.ndarray) -> np.ndarray:
    out = np.zeros_like(x, dtype=float)
    for p in ("top", "bottom"):
        sel = plates == p
        if sel.sum() >= 2:
            out[sel] = x[sel] - x[sel].mean()
    return out


def parity_signs(t: np.ndarray, f0_hz: float) -> np.ndarray:
    """+1/-1 alternating over one plate's impacts at times ``t`` (s, any order): successive impacts flip the
    sign; impacts more than half a drive period apart flip it once per drive cycle between them (rounded),
    so an impact missed in a one-impact-per-cycle regime does not turn the alternation over."""
    t = np.asarray(t, float)
    order = np.argsort(t)
    out = np.zeros(t.size)
    k = 0
    for j, i in enumerate(order):
        if j:
            cycles = (t[i] - t[order[j - 1]]) * f0_hz if f0_hz > 0 else 0.0
            k += max(1, int(round(cycles))) if cycles >= 0.5 else 1
        out[i] = 1.0 if k % 2 == 0 else -1.0
    return out


def cor_patterns(t: np.ndarray, plates: np.ndarray, speed: np.ndarray, residual: np.ndarray, f0_hz: float,
                 n_tests: int = N_SERIES, shapes=("plate", "speed", "phase", "parity"),
                 cor: np.ndarray | None = None) -> list[Mismatch]:
    """Systematic patterns of a COR residual (measured - model COR at each impact): trend and step in
    time, and ``shapes`` of: a plate difference, a within-plate slope with impact speed, with the drive
    phase of the impact (rad), the COR alternating on a plate's successive impacts (per plate,
    :func:`parity_signs`; ``cor``, the measured CORs, gives the two alternating values' means)."""
    t, plates, speed, r = (np.asarray(x) for x in (t, plates, speed, residual))
    ok = np.isfinite(r)
    cor = None if cor is None else np.asarray(cor, float)[ok]
    t, plates, speed, r = t[ok].astype(float), plates[ok], speed[ok].astype(float), r[ok].astype(float)
    if r.size < 2 * MIN_SPLIT:
        return []
    cols = {}
    if "plate" in shapes and (plates == "top").sum() >= 2 and (plates == "bottom").sum() >= 2:
        cols["plate"] = _centre((plates == "top").astype(float))
    if "speed" in shapes:
        cols["speed"] = _within(speed, plates)
    if "phase" in shapes:
        z = np.exp(2j * np.pi * f0_hz * t)
        dev = np.zeros_like(t)
        for p in ("top", "bottom"):
            sel = plates == p
            if sel.sum() >= 2:
                dev[sel] = np.angle(z[sel] * np.conj(np.mean(z[sel])))   # rad from the plate's mean phase
        cols["phase"] = _within(dev, plates)
    signs = {}
    if "parity" in shapes:
        for p in ("top", "bottom"):
            sel = plates == p
            if sel.sum() >= 2 * MIN_SPLIT:
                x = np.zeros_like(t)
                x[sel] = parity_signs(t[sel], f0_hz)
                signs[p] = x.copy()
                x[sel] -= x[sel].mean()
                cols[f"parity_{p}"] = x
    scale = SeriesScale(floor=MIN_COR_RMS, unit_scale=1.0, unit="cor", rms_floor=True)
    found = _series_pursuit("cor", t, r, cols, scale, None, n_tests)
    for m in found:
        if m.shape.startswith("parity_"):
            m.shape, m.plate = "parity", m.shape[len("parity_"):]
            x = signs[m.plate]   # the pursuit's size, c (max - min) of the +-1 column, is even - odd
            if cor is not None:
                m.levels = (float(np.mean(cor[x > 0])), float(np.mean(cor[x < 0])))
            sel = plates == m.plate
            m.t_from_s, m.t_to_s = float(t[sel].min()), float(t[sel].max())
    return found


def systematic_mismatch(meas: Measured, model: FittedModel, sigma_s_m: float, sigma_f_m: float,
                        fps: float, structure: list[Mismatch] | None = None) -> list[Mismatch]:
    """Every systematic pattern the final ``model`` leaves (see the module docstring). ``structure``: the
    structure track's patterns when already found (they do not depend on the model)."""
    out = (list(structure) if structure is not None
           else structure_mismatch(meas.t_s, meas.structure_m, sigma_s_m, meas.frequency_hz, fps))
    out = drive_patterns(out, meas)
    out += level_mismatch(meas, model, sigma_f_m)
    imp, residual = model.impacts, model.cor.residual
    if drive_change(meas) is not None:
        imp, residual = drive_following_cor(meas, model)
    out += cor_patterns(imp.t_s, imp.plate, imp.speed, residual, meas.frequency_hz, cor=imp.cor)
    return out


def drive_following_cor(meas: Measured, model: FittedModel) -> tuple[ImpactSet, np.ndarray]:
    """The model's impacts with the structure velocity the identification measured at each (its local structure
    fit, which follows a drive that does not hold still) instead of the model's stationary sine, their CORs
    recomputed and the model's COR law refitted on them: (impacts, COR residual). Used for the COR patterns when
    the drive is not stationary: a stationary sine's velocity error at the impacts moves with the drive (a step
    in the CORs where the drive's amplitude steps) and is not the contact's."""
    imp = model.impacts
    vs = np.array([meas.impacts[int(i)].v_structure_mps for i in imp.index], dtype=float)
    den = imp.v_before - vs
    ok = np.isfinite(vs) & (np.abs(den) > 1e-6)
    vs = np.where(ok, vs, imp.v_structure)
    den = imp.v_before - vs
    cor = -(imp.v_after - vs) / den
    moved = ImpactSet(index=imp.index, t_s=imp.t_s, plate=imp.plate, v_before=imp.v_before, v_after=imp.v_after,
                      v_structure=vs, cor=cor, cor_std=imp.cor_std)
    return moved, fit_cor(moved, COR_TERMS[model.cor.kind], model.cor.kind).residual


def in_drive_band(frequency_hz: float | None, meas: Measured) -> bool:
    """Whether a structure frequency lies within +-1 / window (the windowed drive model's bandwidth) of a drive
    harmonic 1..DRIVE_HARMONICS, the drive not being stationary (else False: a stationary drive has no band)."""
    drive = drive_change(meas)
    if drive is None or frequency_hz is None:
        return False
    window = drive.get("window_s")
    half = 1.0 / float(window) if window else 0.25 * meas.frequency_hz
    return any(abs(frequency_hz - k * meas.frequency_hz) < half for k in range(1, DRIVE_HARMONICS + 1))


def drive_patterns(patterns: list[Mismatch], meas: Measured) -> list[Mismatch]:
    """``patterns`` with the structure's periodic ones within the drive band (:func:`in_drive_band`) replaced by one
    ``drive`` pattern saying what the drive did (module docstring); unchanged when the drive is stationary, or
    nothing lies in the band, or it was done already."""
    band = [m for m in patterns
            if m.series == "structure" and m.shape == "periodic" and in_drive_band(m.frequency_hz, meas)]
    if not band or any(m.shape == "drive" for m in patterns):
        return patterns
    drive = drive_change(meas)
    amp, ph = drive.get("amplitude") or {}, drive.get("phase") or {}
    changed = bool(amp.get("changed"))
    size, unit = ((1e3 * float(amp["change_mm"]), "um") if changed and amp.get("change_mm") is not None
                  else (float(ph.get("span_rad") or 0.0), "rad"))
    ps = [float(x["p_value"]) for x in (amp, ph) if x.get("p_value") is not None]
    mark = Mismatch(series="structure", shape="drive", size=size, unit=unit, t_from_s=meas.t_first_s,
                    t_to_s=meas.t_last_s, p_value=min(ps) if ps else 0.0, statistic=float(amp.get("z") or 0.0),
                    step_time_s=float(amp["t_s"]) if changed and amp.get("t_s") is not None else None,
                    note=drive_change_words(drive), absorbed_hz=tuple(float(m.frequency_hz) for m in band))
    ids = {id(m) for m in band}
    rest = [m for m in patterns if id(m) not in ids]
    first = next(i for i, m in enumerate(patterns) if id(m) in ids)
    return rest[:first] + [mark] + rest[first:]


def contact_scatter(model: FittedModel, patterns: list[Mismatch], alpha: float = ALPHA_FAMILY) -> dict:
    """The random part of the per-impact COR, per plate and pooled: sigma (after the final COR law and
    the systematic COR patterns found), the COR measurement-noise sigma (RMS of the identification's
    cor_std), and a chi-square test of the scatter against that noise: chi2 = sum(r^2) / noise^2 on the
    residual's degrees of freedom; ``exceeds_noise`` when its p-value < ``alpha``."""
    imp = model.impacts
    r = np.asarray(model.cor.residual, float).copy()
    n_par = model.cor.p
    for m in patterns:
        if m.series == "cor" and m.fit is not None:
            r = r - m.fit
            n_par += 2 if m.shape == "step" else 1
    n = r.size
    out = {}
    for name, sel in (("top", imp.plate == "top"), ("bottom", imp.plate == "bottom"), ("all", np.ones(n, bool))):
        k = int(sel.sum())
        dof = k - n_par * k / max(n, 1)
        if k < 2 or dof <= 0:
            out[name] = {"n": k, "sigma": None, "noise_sigma": None, "exceeds_noise": None, "p_value": None}
            continue
        sse = float((r[sel] ** 2).sum())
        stds = np.asarray(imp.cor_std, float)[sel]
        stds = stds[np.isfinite(stds) & (stds > 0)]
        noise = float(np.sqrt(np.mean(stds ** 2))) if stds.size else 0.0
        sigma = math.sqrt(sse / dof)
        if noise > 0:
            chi = sse / noise ** 2
            p = chi2_sf(chi, dof)
        else:
            chi, p = float("inf"), 0.0
        out[name] = {"n": k, "sigma": _num(sigma), "noise_sigma": _num(noise), "chi2": _num(chi), "dof": _num(dof),
                     "p_value": _num(p), "exceeds_noise": bool(p < alpha)}
    allp = out["all"]
    if allp.get("sigma") is not None:
        verdict = ("exceeds the measurement noise: the contact itself scatters (random, not a model error)"
                   if allp["exceeds_noise"] else "is within the measurement noise")
        out["note"] = (f"per-impact COR scatter sigma {allp['sigma']:.4f} vs measurement noise "
                       f"{allp['noise_sigma']:.4f} (chi2 = {allp['chi2']:.3g} on {allp['dof']:.1f} dof, "
                       f"p = {allp['p_value']:.1e}) {verdict}")
    return out
