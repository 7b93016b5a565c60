"""Accelerometer impacts: high-pass, detection, isolation, spectra (Fig. 6-7), plate, clipping, clock offset.

Detection rule: both channels are high-passed (zero-phase Butterworth, ``sosfiltfilt``, 100 Hz default)
to remove the excitation. The detection signal is s = |hp_upper| + |hp_lower|; its noise level is
robust: sigma = 1.4826 * MAD(s - median(s)) (the impact ringing occupies a minority of samples). An
impact starts at the first sample where s > median(s) + k_sigma * sigma (k_sigma = 8 by default); after
a detection, the detector is blind for a refractory time (a quarter of the excitation period by default),
so that the ringing of one impact is not counted twice.
Each impact is isolated over half an excitation period from its onset (as in the paper) and its
spectrum is |rfft| of that segment per channel; the spectra are averaged over all impacts.
Plate attribution: the channel with the larger energy (sum of squares of the high-passed signal) over
the first ``attribution_s`` (2 ms) after the onset, cut at the next onset (the half-period segment can
hold the next impact).
Clipping: a run of >= 3 consecutive samples equal to the channel's extreme value (max or min) is
reported with the channel name and time.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from vibro_io.accel import AccelData
from vibro_model.errors import AccelError


@dataclass
class AccelImpact:
    """One accelerometer impact. Energies are sum(a^2) dt of the high-passed signal over the attribution
    window (m^2/s^3); ``peak_mps2`` is the peak |high-passed acceleration| on the attributed channel;
    ``dominant_frequencies_hz`` the main peaks of that channel's spectrum over the isolated segment;
    ``clipped`` when the raw signal of a channel sits at its extreme value for >= 3 consecutive samples
    inside the attribution window."""

    t_s: float              # onset, DAQ clock (s)
    plate: str              # "top" | "bottom" (channel with the larger energy)
    energy_upper: float
    energy_lower: float
    peak_mps2: float
    dominant_frequencies_hz: list[float] = field(default_factory=list)
    clipped: bool = False


def _flat_extreme(x: np.ndarray, min_run: int = 3) -> bool:
    """True when the largest |x| of the segment is held for >= min_run consecutive samples."""
    if x.size < min_run:
        return False
    m = np.abs(x) >= np.max(np.abs(x))
    run = 0
    for v in m:
        run = run + 1 if v else 0
        if run >= min_run:
            return True
    return False


def _spectrum_peaks(seg: np.ndarray, fs: float, n_peaks: int = 3) -> list[float]:
    mag = np.abs(np.fft.rfft(seg))
    freqs = np.fft.rfftfreq(seg.size, 1.0 / fs)
    if not mag.any():
        return []
    from scipy.signal import find_peaks  # here, not at import: scipy.signal costs ~1.3 s to import

    idx, props = find_peaks(mag, prominence=0.05 * mag.max())
    order = np.argsort(props["prominences"])[::-1][:n_peaks]
    return sorted(float(freqs[idx[k]]) for k in order)


def _make_impact(t: float, hu: np.ndarray, hl: np.ndarray, n_att: int, raw_u: np.ndarray, raw_l: np.ndarray,
                 fs: float) -> AccelImpact:
    """hu/hl: high-passed isolated segments starting at the onset; the first n_att samples attribute."""
    dt = 1.0 / fs
    eu = float(hu[:n_att] @ hu[:n_att]) * dt
    el = float(hl[:n_att] @ hl[:n_att]) * dt
    top = eu >= el
    ch = hu if top else hl
    return AccelImpact(float(t), "top" if top else "bottom", eu, el, float(np.max(np.abs(ch[:n_att]))),
                       _spectrum_peaks(ch, fs), _flat_extreme(raw_u[:n_att]) or _flat_extreme(raw_l[:n_att]))


@dataclass(kw_only=True)
class AccelAnalysis:
    impacts: list[AccelImpact]
    freqs_hz: np.ndarray
    mean_spectrum_upper: np.ndarray
    mean_spectrum_lower: np.ndarray
    peaks_hz: list[float]
    threshold: float
    sample_rate_hz: float
    clipping: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class ClockLine:
    """The camera-to-DAQ clock relation t_daq = t_camera + offset_s + rate * (t_camera - t_ref_s): ``offset_s``
    (s) the DAQ's lead at camera time ``t_ref_s`` (s), ``rate`` (dimensionless, ppm x 1e-6) how much faster the
    DAQ's clock runs than the camera's."""

    offset_s: float
    rate: float = 0.0
    t_ref_s: float = 0.0

    def daq_s(self, t_camera_s):
        """DAQ-clock times (s) of camera-clock times ``t_camera_s`` (s; scalar or array)."""
        t = np.asarray(t_camera_s, float)
        return t + self.offset_s + self.rate * (t - self.t_ref_s)

    def camera_s(self, t_daq_s):
        """Camera-clock times (s) of DAQ-clock times ``t_daq_s`` (s; scalar or array): the inverse of
        :meth:`daq_s`."""
        t = np.asarray(t_daq_s, float)
        return self.t_ref_s + (t - self.offset_s - self.t_ref_s) / (1.0 + self.rate)


@dataclass(kw_only=True)
class ClockOffset:
    """Camera-to-DAQ clock relation t_daq = t_camera + offset_s + rate * (t_camera - t_ref_s), from ``n_matched``
    impact pairs (``rate_ppm`` = rate x 1e6; 0 unless the fitted rate is significant, see
    :func:`estimate_clock_offset`; with rate 0 it is the plain offset t_daq = t_camera + offset_s).

    ``determined`` is False when the matching cannot tell the offset (``reason`` says why: too few
    impacts in common, or another offset, typically a shaker period away, matching nearly as many);
    ``offset_s`` is then only the best candidate and must not be used (see :attr:`known_offset_s`).
    ``matched_span_s`` is the camera-clock interval of the matched DIC impacts (the overlap the offset
    rests on); ``candidates`` the other offsets tried, each (offset_s, n_matched), best first.
    ``residual_std_s`` is the std (s) of the matched pairs' differences about the relation used (with the rate
    when it is kept). ``offset_std_s`` and ``rate_std_ppm`` are 1-sigma; ``fitted_rate_ppm`` is the least-squares
    rate whether kept or not, ``rate_note`` why it was not kept. ``expected_noise_s`` is the timing noise (s)
    the residuals are judged against, ``residual_warning`` the warning when they exceed it.
    """

    offset_s: float
    n_matched: int
    residual_std_s: float
    determined: bool = True
    reason: str = ""
    matched_span_s: tuple[float, float] | None = None
    n_accel: int = 0
    n_dic: int = 0
    candidates: list[tuple[float, int]] = field(default_factory=list)
    assumption: str = ""
    rate_ppm: float = 0.0
    rate_std_ppm: float | None = None
    fitted_rate_ppm: float | None = None
    rate_note: str = ""
    offset_std_s: float | None = None
    t_ref_s: float = 0.0
    expected_noise_s: float | None = None
    residual_warning: str = ""

    @property
    def known_offset_s(self) -> float | None:
        """The offset (s, at camera time ``t_ref_s``) when it is determined, else None."""
        return self.offset_s if self.determined else None

    @property
    def line(self) -> ClockLine:
        """The relation as a :class:`ClockLine` (the best candidate's when not determined)."""
        return ClockLine(float(self.offset_s), 1e-6 * float(self.rate_ppm), float(self.t_ref_s))

    def camera_s(self, t_daq_s) -> list[float]:
        """DAQ-clock times (s) on the camera clock (s) with the offset and the rate."""
        return [float(x) for x in np.atleast_1d(self.line.camera_s(t_daq_s))]

    def overlap_words(self) -> str:
        span = self.matched_span_s
        where = f" over t = {span[0]:.4f}..{span[1]:.4f} s (camera clock, {span[1] - span[0]:.3f} s)" if span else ""
        return (f"{self.n_matched} of {self.n_accel} accelerometer and {self.n_dic} DIC impacts matched{where}")

    def rate_words(self) -> str:
        """The rate part of the message: empty when the rate is 0 (not kept)."""
        if not self.rate_ppm:
            return ""
        return (f" at t = {self.t_ref_s:.4f} s, DAQ clock rate {self.rate_ppm:+.1f} +- {self.rate_std_ppm or 0.0:.1f} "
                "ppm against the camera's")

    def message(self) -> str:
        """One sentence for the user: the offset and the overlap it rests on, or why it is not determined."""
        if self.determined:
            extra = f" ({self.assumption})" if self.assumption else ""
            return (f"clock offset t_daq - t_camera = {self.offset_s:+.5f} s{self.rate_words()} from "
                    f"{self.overlap_words()}{extra}")
        return f"clock offset not determined: {self.reason}"

    def to_dict(self) -> dict:
        span = self.matched_span_s
        known = self.determined
        return {"determined": bool(self.determined), "offset_s": self.known_offset_s,
                "best_candidate_s": float(self.offset_s), "reason": self.reason or None,
                "n_matched": int(self.n_matched), "n_accel_impacts": int(self.n_accel),
                "n_dic_impacts": int(self.n_dic),
                "matched_span_s": [float(span[0]), float(span[1])] if span else None,
                "matched_duration_s": float(span[1] - span[0]) if span else 0.0,
                "candidates": [{"offset_s": float(o), "n_matched": int(n)} for o, n in self.candidates],
                "assumption": self.assumption or None,
                "message": self.message(),
                "rate_ppm": float(self.rate_ppm) if known else None,
                "rate_std_ppm": _none_or_float(self.rate_std_ppm) if known else None,
                "rate_significant": bool(self.rate_ppm) if known else None,
                "fitted_rate_ppm": _none_or_float(self.fitted_rate_ppm),
                "rate_note": self.rate_note or None,
                "offset_std_s": _none_or_float(self.offset_std_s) if known else None,
                "t_ref_s": float(self.t_ref_s),
                "expected_timing_noise_s": _none_or_float(self.expected_noise_s),
                "residual_warning": self.residual_warning or None}


def _none_or_float(x: float | None) -> float | None:
    return None if x is None else float(x)


#: fewest impacts in common for a clock offset (with fewer, chance coincidences of a periodic motion win)
MIN_MATCHED_IMPACTS = 4


@functools.lru_cache(maxsize=8)
def _highpass_sos(order: int, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """Second-order sections of the Butterworth high-pass (designed once per order, cut-off and rate: a live
    detector filters every block with the same design)."""
    from scipy.signal import butter  # here, not at import (node start-up time)

    return butter(order, cutoff_hz, btype="highpass", fs=fs_hz, output="sos")


def highpass(x: np.ndarray, fs_hz: float, cutoff_hz: float = 100.0, order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth high-pass (sosfiltfilt)."""
    if not 0 < cutoff_hz < 0.5 * fs_hz:
        raise AccelError(f"high-pass cut-off {cutoff_hz} Hz must be in (0, {0.5 * fs_hz:g}) Hz (Nyquist)")
    from scipy.signal import sosfiltfilt  # here, not at import (node start-up time)

    sos = _highpass_sos(int(order), float(cutoff_hz), float(fs_hz))
    x = np.asarray(x, float)
    pad = 3 * (2 * len(sos) + 1)
    if x.size <= pad:
        raise AccelError(f"accelerometer signal of {x.size} samples is too short for the zero-phase "
                         f"high-pass (needs more than {pad})")
    return sosfiltfilt(sos, x)


def warm_up(sample_rate_hz: float, highpass_hz: float = 100.0) -> None:
    """Load and run the detection's numerics once (scipy.signal: about a second of CPU to import, the filter's
    design) so that a live node pays it before its first block, not while the stream runs and the other nodes
    need the cores. Raises :class:`AccelError` for a cut-off the rate cannot carry, as the first block would.

    Parameters
    ----------
    sample_rate_hz
        The DAQ's sample rate (Hz) the blocks will come at.
    highpass_hz
        The high-pass cut-off (Hz) the detection will use.
    """
    from scipy.signal import find_peaks

    t = np.arange(4096) / sample_rate_hz
    x = np.sin(2 * np.pi * 0.25 * sample_rate_hz * t)
    find_peaks(np.abs(highpass(x, sample_rate_hz, highpass_hz)))


def find_clipping(t_s: np.ndarray, x: np.ndarray, channel: str, min_run: int = 3) -> list[dict]:
    """Runs of >= ``min_run`` samples stuck at the channel's max or min: [{channel, t_s, n, value}]."""
    out = []
    for value in (float(np.max(x)), float(np.min(x))):
        at = x == value
        if at.sum() < min_run:
            continue
        edges = np.diff(np.concatenate([[0], at.astype(int), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        for s, e in zip(starts, ends):
            if e - s >= min_run:
                out.append({"channel": channel, "t_s": float(t_s[s]), "n": int(e - s), "value": value})
    return out


def detect_impacts(t_s: np.ndarray, hp_upper: np.ndarray, hp_lower: np.ndarray, k_sigma: float = 8.0,
                   refractory_s: float = 0.01) -> tuple[np.ndarray, float]:
    """Onset sample indices of impacts and the threshold used (see module rule)."""
    s = np.abs(hp_upper) + np.abs(hp_lower)
    med = float(np.median(s))
    sigma = 1.4826 * float(np.median(np.abs(s - med)))
    thr = med + k_sigma * sigma
    above = np.flatnonzero(s > thr)
    onsets = []
    last = -np.inf
    for i in above:
        if t_s[i] - last >= refractory_s:
            onsets.append(i)
            last = t_s[i]
    return np.asarray(onsets, int), thr


def analyse_accel(data: AccelData, frequency_hz: float, highpass_hz: float = 100.0, k_sigma: float = 8.0,
                  refractory_s: float | None = None, n_peaks: int = 5, attribution_s: float = 0.002
                  ) -> AccelAnalysis:
    """Detect impacts on the accelerometers and compute their averaged spectrum (see module rules)."""
    fs = data.sample_rate_hz
    warnings: list[str] = []
    clipping = find_clipping(data.t_s, data.upper_ms2, "upper") + find_clipping(data.t_s, data.lower_ms2, "lower")
    for c in clipping:
        warnings.append(f"accelerometer channel '{c['channel']}' clipped at {c['value']:g} m/s^2 "
                        f"for {c['n']} samples from t = {c['t_s']:.5f} s: impact amplitudes there are wrong")
    hu = highpass(data.upper_ms2, fs, highpass_hz)
    hl = highpass(data.lower_ms2, fs, highpass_hz)
    refr = refractory_s if refractory_s is not None else 0.25 / frequency_hz
    onsets, thr = detect_impacts(data.t_s, hu, hl, k_sigma, refr)
    seg = max(int(round(0.5 / frequency_hz * fs)), 8)
    impacts: list[AccelImpact] = []
    spec_u, spec_l = [], []
    n_att = max(int(round(attribution_s * fs)), 4)
    for m, i in enumerate(onsets):
        j = min(i + seg, data.t_s.size)
        su, sl = hu[i:j], hl[i:j]
        ja = min(i + n_att, onsets[m + 1] if m + 1 < onsets.size else data.t_s.size)
        impacts.append(_make_impact(data.t_s[i], su, sl, ja - i, data.upper_ms2[i:j], data.lower_ms2[i:j], fs))
        if j - i == seg:
            spec_u.append(np.abs(np.fft.rfft(su)))
            spec_l.append(np.abs(np.fft.rfft(sl)))
    freqs = np.fft.rfftfreq(seg, 1.0 / fs)
    mu = np.mean(spec_u, axis=0) if spec_u else np.zeros(freqs.size)
    ml = np.mean(spec_l, axis=0) if spec_l else np.zeros(freqs.size)
    peaks: list[float] = []
    tot = mu + ml
    if tot.any():
        from scipy.signal import find_peaks

        idx, props = find_peaks(tot, prominence=0.05 * tot.max())
        order = np.argsort(props["prominences"])[::-1][:n_peaks]
        peaks = sorted(float(freqs[idx[k]]) for k in order)
    if not impacts:
        warnings.append("no impact found on the accelerometers")
    return AccelAnalysis(impacts=impacts, freqs_hz=freqs, mean_spectrum_upper=mu, mean_spectrum_lower=ml,
                         peaks_hz=peaks, threshold=thr, sample_rate_hz=fs, clipping=clipping, warnings=warnings)


def _nearest(a: np.ndarray, pred: np.ndarray, tol_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Per predicted DAQ time ``pred`` (s), the signed distance (s) to the nearest accelerometer time of ``a``,
    and the mask of those within ``tol_s``."""
    k = np.clip(np.searchsorted(a, pred), 1, max(a.size - 1, 1))
    cand = np.stack([a[k - 1], a[np.minimum(k, a.size - 1)]]) - pred
    r = cand[np.argmin(np.abs(cand), axis=0), np.arange(pred.size)]
    return r, np.abs(r) <= tol_s


def _match(a: np.ndarray, d: np.ndarray, off: float, tol_s: float) -> tuple[np.ndarray, np.ndarray]:
    """For offset ``off``: per DIC time, the signed distance (s) to the nearest accelerometer time on the
    camera clock, and the mask of those within ``tol_s``."""
    return _nearest(a, d + off, tol_s)


def _refine(a: np.ndarray, d: np.ndarray, off: float, tol_s: float) -> tuple[float, int, float]:
    """(offset, n_matched, residual std) after two median refinements from ``off``."""
    for _ in range(2):
        r, sel = _match(a, d, off, tol_s)
        if not sel.any():
            return off, 0, 0.0
        off += float(np.median(r[sel]))
    r, sel = _match(a, d, off, tol_s)
    return off, int(sel.sum()), float(np.std(r[sel])) if sel.sum() > 1 else 0.0


#: fewest matched pairs for a rate (with fewer, the residual std that scales the rate's sigma is itself uncertain
#: by more than a quarter)
MIN_RATE_PAIRS = 8
#: a fitted rate is kept only when it exceeds this many of its standard deviations
RATE_SIGMAS = 3.0
#: largest |rate| (ppm) taken as a clock's drift: crystals are specified to +-20..500 ppm; beyond this the pairs
#: say something else (a clock jump, a wrong sample rate: rig_consistency reports frame-rate errors from 0.5 %)
MAX_RATE_PPM = 2000.0
#: floor (s) of the pairs' timing scatter in the fit's stds: 0.1 us, far below a 50 kHz sample (20 us); keeps
#: noise-free times from making a 1e-10 ppm rate "significant"
TIMING_FLOOR_S = 1e-7
#: rematch-and-refit rounds of the offset + rate fit (each matches the impacts the previous line brings within
#: ``tol_s``; it stops earlier when the matched set no longer changes)
RATE_ROUNDS = 5


@dataclass(frozen=True, kw_only=True)
class _LineFit:
    """Least-squares offset + rate on matched pairs: the line, the 1-sigma stds of its offset (s, at ``t_ref_s``)
    and rate (dimensionless), and the pairs it rests on (count, camera-clock span s, residual std s)."""

    line: ClockLine
    offset_std_s: float
    rate_std: float
    n: int
    span_s: float
    residual_std_s: float


def _lsq_line(t_camera_s: np.ndarray, diff_s: np.ndarray) -> _LineFit:
    """Fit diff = t_daq - t_camera = offset + rate (t_camera - t_ref) by least squares, t_ref the mean camera time
    (offset and rate then uncorrelated); stds from the residual scatter (floored at :data:`TIMING_FLOOR_S`)."""
    n = t_camera_s.size
    t_ref = float(np.mean(t_camera_s))
    x = t_camera_s - t_ref
    sxx = float(x @ x)
    off = float(np.mean(diff_s))
    rate = float(x @ (diff_s - off)) / sxx if sxx > 0 else 0.0
    res = diff_s - off - rate * x
    scatter = max(float(np.sqrt(res @ res / max(n - 2, 1))), TIMING_FLOOR_S)
    return _LineFit(line=ClockLine(off, rate, t_ref), offset_std_s=scatter / np.sqrt(n),
                    rate_std=scatter / np.sqrt(sxx) if sxx > 0 else np.inf, n=int(n),
                    span_s=float(np.ptp(t_camera_s)), residual_std_s=float(np.std(res)))


def _fit_line(a: np.ndarray, d: np.ndarray, seed: ClockLine, tol_s: float) -> _LineFit | None:
    """Offset + rate from ``seed``: match the DIC times ``d`` to the accelerometer times ``a`` within ``tol_s``
    with the current line, fit the line on the matched pairs, rematch with it, refit, up to :data:`RATE_ROUNDS`
    times (each round can match the pairs the drift had carried out of reach). None with fewer than
    :data:`MIN_RATE_PAIRS` pairs."""
    line, fit, prev = seed, None, None
    for _ in range(RATE_ROUNDS):
        r, sel = _nearest(a, line.daq_s(d), tol_s)
        if sel.sum() < MIN_RATE_PAIRS or (prev is not None and np.array_equal(sel, prev)):
            break
        prev = sel
        fit = _lsq_line(d[sel], line.daq_s(d[sel]) + r[sel] - d[sel])
        if abs(fit.line.rate) > 2e-6 * MAX_RATE_PPM:   # runaway (no crystal drifts so): stop, the refusal says why
            break
        line = fit.line
    return fit


def _rate_refusal(fit: _LineFit, n_constant: int) -> str:
    """Why the fitted rate is not kept (empty when it is): too few pairs, beyond :data:`MAX_RATE_PPM`, within
    :data:`RATE_SIGMAS` of its std, a matched span too short for the rate to move its ends by more than the
    timing scatter, or fewer impacts matched than with the constant offset (``n_constant``)."""
    ppm, std_ppm = 1e6 * fit.line.rate, 1e6 * fit.rate_std
    drift_s = abs(fit.line.rate) * fit.span_s
    scatter_s = max(fit.residual_std_s, TIMING_FLOOR_S)
    if fit.n < MIN_RATE_PAIRS:
        return f"rate not fitted: {fit.n} matched impacts, at least {MIN_RATE_PAIRS} needed"
    if abs(ppm) > MAX_RATE_PPM:
        return (f"fitted rate {ppm:+.0f} ppm is beyond +-{MAX_RATE_PPM:g} ppm, not a crystal's drift (a clock jump? "
                "a wrong sample rate?): not applied")
    if abs(ppm) <= RATE_SIGMAS * std_ppm:
        return f"rate {ppm:+.2f} +- {std_ppm:.2f} ppm is not significant (within {RATE_SIGMAS:g} sigma): taken as 0"
    if drift_s <= scatter_s:
        return (f"rate {ppm:+.1f} +- {std_ppm:.1f} ppm moves the ends of the {fit.span_s:.3f} s matched span by "
                f"{1e6 * drift_s:.1f} us, within the pairs' {1e6 * scatter_s:.1f} us scatter: span too short to tell, "
                "taken as 0")
    if fit.n < n_constant:
        return f"the rate matches {fit.n} impacts, the constant offset {n_constant}: taken as 0"
    return ""


def _clock_fit(a: np.ndarray, d: np.ndarray, seed_s: float, tol_s: float) -> dict:
    """The clock relation from the offset ``seed_s``: the constant offset refined by medians (:func:`_refine`),
    then offset + rate (:func:`_fit_line`), the rate kept only when :func:`_rate_refusal` finds no reason against
    it. Returns the :class:`ClockOffset` fields it sets (offset_s, n_matched, residual_std_s, matched_span_s and
    the rate fields)."""
    off, n, sd = _refine(a, d, seed_s, tol_s)
    _, sel = _match(a, d, off, tol_s)
    span = (float(d[sel][0]), float(d[sel][-1])) if sel.any() else None
    out = {"offset_s": float(off), "n_matched": int(n), "residual_std_s": float(sd), "matched_span_s": span,
           "t_ref_s": float(np.mean(d[sel])) if sel.any() else 0.0,
           "offset_std_s": max(sd, TIMING_FLOOR_S) / np.sqrt(n) if n else None}
    fit = _fit_line(a, d, ClockLine(off, 0.0, out["t_ref_s"]), tol_s) if n >= MIN_RATE_PAIRS else None
    if fit is None:
        out["rate_note"] = f"rate not fitted: {n} matched impacts, at least {MIN_RATE_PAIRS} needed"
        return out
    out.update(fitted_rate_ppm=1e6 * fit.line.rate, rate_std_ppm=1e6 * fit.rate_std)
    out["rate_note"] = _rate_refusal(fit, n)
    if out["rate_note"]:
        return out
    r, sel = _nearest(a, fit.line.daq_s(d), tol_s)
    out.update(offset_s=fit.line.offset_s, n_matched=int(sel.sum()), residual_std_s=float(np.std(r[sel])),
               matched_span_s=(float(d[sel][0]), float(d[sel][-1])), t_ref_s=fit.line.t_ref_s,
               offset_std_s=fit.offset_std_s, rate_ppm=1e6 * fit.line.rate)
    return out


def _differences_within(a: np.ndarray, d: np.ndarray, max_offset_s: float, rows: int = 256) -> np.ndarray:
    """Every difference a_i - d_j (a, d sorted) within +-``max_offset_s``: the pairs of the whole matrix
    that pass, taken block by block (``rows`` of a against the d that can lie within reach of them), so
    memory and time grow with the pairs that pass (linear in the record's length), not with a.size x d.size."""
    reach = max_offset_s * (1.0 + 1e-9) + 1e-12      # a window a little wider than the test below
    out = []
    for i in range(0, a.size, rows):
        blk = a[i:i + rows]
        lo, hi = np.searchsorted(d, blk[0] - reach, "left"), np.searchsorted(d, blk[-1] + reach, "right")
        diffs = (blk[:, None] - d[None, lo:hi]).ravel()
        out.append(diffs[np.abs(diffs) <= max_offset_s])
    return np.concatenate(out) if out else np.empty(0)


def _candidate_seeds(diffs: np.ndarray, max_offset_s: float, tol_s: float) -> list[float]:
    """Up to 8 candidate offsets (s): the centres of the densest pairs of ``tol_s`` histogram bins of the
    differences, each more than 3 ``tol_s`` from the others."""
    edges = np.arange(-max_offset_s, max_offset_s + tol_s, tol_s)
    counts, edges = np.histogram(diffs, bins=edges)
    pair = counts[:-1] + counts[1:] if counts.size > 1 else counts
    centres = edges[1:-1] if counts.size > 1 else 0.5 * (edges[:1] + edges[1:])
    seeds: list[float] = []
    for k in np.argsort(pair, kind="stable")[::-1]:
        if pair[k] < 2 and seeds:
            break
        c = float(centres[k])
        if all(abs(c - s) > 3 * tol_s for s in seeds):
            seeds.append(c)
        if len(seeds) >= 8:
            break
    return seeds


def _started_together(off: float, n: int, others: list[tuple[float, int]], period_s: float,
                      spans: tuple[tuple[float, float], tuple[float, float]]) -> tuple[int, str]:
    """The matches a rival offset needs to make ``off`` (matching ``n``) ambiguous, and the stated assumption:
    n when the records (``spans``: accelerometer on the DAQ clock, camera on the camera clock, s) last equally
    long and ``off`` aligns their starts (within half a period), else n - 1 and none."""
    accel_span_s, camera_span_s = spans
    dur_a = accel_span_s[1] - accel_span_s[0]
    dur_c = camera_span_s[1] - camera_span_s[0]
    aligned = accel_span_s[0] - camera_span_s[0]
    if not (abs(dur_a - dur_c) < 0.5 * period_s and abs(off - aligned) < 0.5 * period_s):
        return n - 1, ""
    assumption = ""
    if any(m >= n - 1 for o, m in others):
        assumption = ("assuming the two records were started together: they last equally long and this "
                      "offset aligns their starts; a regular motion also matches "
                      + ", ".join(f"{m} at {o:+.5f} s" for o, m in others if m >= n - 1))
    return n, assumption


def estimate_clock_offset(accel_times_s, dic_times_s, period_s: float | None = None, tol_s: float = 0.0005,
                          max_offset_s: float = 1.0, min_matched: int = MIN_MATCHED_IMPACTS,
                          accel_span_s: tuple[float, float] | None = None,
                          camera_span_s: tuple[float, float] | None = None) -> ClockOffset | None:
    """Offset (s) with t_daq = t_camera + offset, matching accelerometer and DIC impact times.

    All pairwise differences t_daq - t_camera within +-``max_offset_s`` are histogrammed with bins of
    ``tol_s``; the densest peaks are candidate offsets (the true offset collects one difference per
    matched impact), each refined as the median of its matched differences and scored by the number of
    DIC impacts that have an accelerometer impact within ``tol_s``. With ``period_s`` (the shaker
    period), the best candidate shifted by whole periods is scored too: a periodic motion matches
    itself one period later, and only the edges of the overlap tell those offsets apart.

    The offset is *not determined* (``determined=False``, with the reason) when fewer than
    ``min_matched`` impacts match, or when another candidate (more than 3 ``tol_s`` away) matches at
    least as many impacts minus one: then the records do not say which offset is right (e.g. an
    accelerometer record covering half the video of a regular motion fits at several whole periods).
    One prior breaks such a tie, and is stated (``assumption``): when both records are given
    (``accel_span_s`` on the DAQ clock, ``camera_span_s`` on the camera clock), last equally long (within half
    a period) and the best offset aligns their starts (within half a period), the records were started
    together, so a whole-period shift, which shortens their overlap, must match strictly more impacts to
    rival it. None when no pair of impacts lies within ``max_offset_s``.

    Clock rate: a DAQ crystal running fast by a few hundred ppm moves the differences along the record (0.5 ms
    over 1 s at 500 ppm), so each candidate is also fitted as t_daq = t_camera + offset + rate (t_camera - t_ref)
    (t_ref the mean matched DIC time, where offset and rate are uncorrelated): least squares on the pairs matched
    with the median offset, then rematched with the line and refitted until the pairs stop changing (at most
    :data:`RATE_ROUNDS` rounds; each round reaches the pairs the drift had carried beyond ``tol_s``). The rate is
    kept (``rate_ppm``) only with at least :data:`MIN_RATE_PAIRS` pairs, within +-:data:`MAX_RATE_PPM`, beyond
    :data:`RATE_SIGMAS` of its std, when it moves the ends of the matched span by more than the pairs' scatter and
    matches no fewer impacts than the constant offset; else the rate is 0 (``rate_note`` says why) and the offset
    is the median one, exactly as without the rate fit.
    """
    a = np.sort(np.asarray(accel_times_s, float))
    d = np.sort(np.asarray(dic_times_s, float))
    if a.size == 0 or d.size == 0:
        return None
    diffs = _differences_within(a, d, max_offset_s)
    if diffs.size == 0:
        return None
    scored = [_clock_fit(a, d, s, tol_s) for s in _candidate_seeds(diffs, max_offset_s, tol_s)]
    if period_s:
        scored += _period_shifts(a, d, max(scored, key=_score), period_s, (tol_s, max_offset_s))
    scored.sort(key=_score, reverse=True)
    best = scored[0]
    off, n = best["offset_s"], best["n_matched"]
    if n == 0:
        return None
    others: list[tuple[float, int]] = []
    for c in scored[1:]:
        o, m = c["offset_s"], c["n_matched"]
        if abs(o - off) > 3 * tol_s and all(abs(o - x) > 3 * tol_s for x, _ in others) and m > 0:
            others.append((float(o), int(m)))
    others = others[:5]
    slack, assumption = n - 1, ""
    if period_s and accel_span_s is not None and camera_span_s is not None:
        off_at_start = float(ClockLine(off, 1e-6 * best.get("rate_ppm", 0.0), best["t_ref_s"]).daq_s(camera_span_s[0])
                             - camera_span_s[0])
        slack, assumption = _started_together(off_at_start, n, others, period_s, (accel_span_s, camera_span_s))
    reason = _undetermined_reason(best, [(o, m) for o, m in others if m >= slack], (a.size, d.size),
                                  min_matched, period_s)
    return ClockOffset(**best, determined=not reason, reason=reason, n_accel=int(a.size), n_dic=int(d.size),
                       candidates=others, assumption="" if reason else assumption)


def _score(fit: dict) -> tuple[int, float]:
    """Ranks candidate fits: more impacts matched, then the smaller residual."""
    return fit["n_matched"], -fit["residual_std_s"]


def _period_shifts(a: np.ndarray, d: np.ndarray, best: dict, period_s: float, tols: tuple[float, float]) -> list[dict]:
    """The fits seeded at the best candidate's offset shifted by whole shaker periods (``period_s``, s) within
    +-max_offset_s (``tols`` = (tol_s, max_offset_s), s): a periodic motion matches itself one period later."""
    tol_s, max_offset_s = tols
    n_per = int(max_offset_s / period_s)
    off = best["offset_s"]
    return [_clock_fit(a, d, off + k * period_s, tol_s) for k in range(-n_per, n_per + 1)
            if k != 0 and abs(off + k * period_s) <= max_offset_s]


def _undetermined_reason(best: dict, rivals: list[tuple[float, int]], sizes: tuple[int, int], min_matched: int,
                         period_s: float | None) -> str:
    """Why the best fit does not determine the offset (empty when it does): fewer than ``min_matched`` impacts
    matched, or a rival offset (offset_s, n_matched) matching about as many; ``sizes``: the numbers of
    accelerometer and DIC impacts."""
    off, n = best["offset_s"], best["n_matched"]
    n_acc, n_dic = sizes
    if n < min_matched:
        return (f"too little overlap: only {n} impact(s) in common between the accelerometers ({n_acc}) and "
                f"DIC ({n_dic}), at least {min_matched} needed")
    if not rivals:
        return ""
    o2, m2 = max(rivals, key=lambda x: x[1])
    shift = o2 - off
    per = f" ({shift / period_s:+.2f} shaker periods)" if period_s else ""
    return (f"ambiguous: offset {off:+.5f} s matches {n} impacts and {o2:+.5f} s{per} matches {m2}; "
            "the overlap of the two records is too regular to tell them apart "
            f"({n_acc} accelerometer impacts, {n_dic} DIC impacts)")


#: the clock relation's residual std may reach this multiple of the expected timing noise before it is warned
#: about (the std of n >= 8 pairs is within +-25 % of the noise's; the noise model is a sample's and a DIC time's)
RESIDUAL_NOISE_FACTOR = 3.0


def expected_timing_noise_s(sample_rate_hz: float, dic_time_stds_s=(), frame_period_s: float | None = None) -> float:
    """The std (s) of a matched pair's difference t_daq - t_camera when the clocks follow offset + rate.

    Parameters
    ----------
    sample_rate_hz
        The DAQ's sample rate (Hz): an accelerometer onset is the first sample over the threshold, so its time is
        quantised to a sample, uniformly within it: std 1 / (rate sqrt 12) (5.8 us at 50 kHz; the latency common
        to all impacts goes into the offset).
    dic_time_stds_s
        The 1-sigma times (s) of the matched DIC impacts (the flight fits' ``t_std_s``); their median is the DIC
        part. Without a finite one, ``frame_period_s`` / sqrt 12: an impact located to a frame.
    frame_period_s
        The camera's frame period (s), for DIC times without their own std (0.29 ms at 1000 fps).
    """
    onset_s = 1.0 / (float(sample_rate_hz) * np.sqrt(12.0))
    stds = np.asarray([x for x in dic_time_stds_s if x is not None], float)
    stds = stds[np.isfinite(stds)]
    if stds.size:
        dic_s = float(np.median(stds))
    else:
        dic_s = float(frame_period_s or 0.0) / np.sqrt(12.0)
    return float(np.hypot(onset_s, dic_s))


def judge_residuals(offset: ClockOffset, expected_noise_s: float) -> ClockOffset:
    """``offset`` with ``expected_noise_s`` (s, :func:`expected_timing_noise_s`) stated and, when it is determined
    and its residual std exceeds :data:`RESIDUAL_NOISE_FACTOR` times that noise, the ``residual_warning``: the two
    clocks are then not an offset and a constant rate apart (a clock jump, a changing rate, impacts paired wrongly)
    and the accelerometer times on the camera clock are uncertain by about the residual."""
    from dataclasses import replace

    warning = ""
    limit_s = RESIDUAL_NOISE_FACTOR * expected_noise_s
    if offset.determined and offset.residual_std_s > limit_s:
        rate = f"offset + {offset.rate_ppm:+.1f} ppm rate" if offset.rate_ppm else "constant offset"
        warning = (f"camera-DAQ clock residuals {1e6 * offset.residual_std_s:.1f} us (std over {offset.n_matched} "
                   f"matched impacts, {rate}) exceed {RESIDUAL_NOISE_FACTOR:g} x the expected timing noise "
                   f"{1e6 * expected_noise_s:.1f} us: the clocks are not related by an offset and a constant rate "
                   "(a clock jump? a changing rate?); accelerometer impact times on the camera clock are uncertain "
                   "by about the residual")
    return replace(offset, expected_noise_s=float(expected_noise_s), residual_warning=warning)


@dataclass(frozen=True, kw_only=True)
class DetectorWindows:
    """Time windows of :class:`AccelImpactDetector` (s): the refractory time after an impact (None: a quarter
    of the excitation period), the filter context each side of a block, the warm-up that sets the threshold,
    and the attribution window of an impact to a plate."""

    refractory_s: float | None = None
    context_s: float = 0.03
    warmup_s: float = 0.2
    attribution_s: float = 0.002


class AccelImpactDetector:
    """Block-by-block impact detection (the core of the impact_detector node).

    The same rule as :func:`analyse_accel`: the high-pass is zero-phase, so each block is filtered
    together with ``context_s`` of samples before and after it; detections are therefore final
    ``context_s`` after the samples arrive (default 30 ms = 3 time constants of a 100 Hz filter).
    The threshold median + k_sigma * 1.4826 MAD comes from the first ``warmup_s`` of data (or
    ``threshold`` if given) and stays fixed. Impacts carry the DAQ clock time of their onset.
    """

    def __init__(self, sample_rate_hz: float, frequency_hz: float, *, highpass_hz: float = 100.0,
                 k_sigma: float = 8.0, windows: DetectorWindows | None = None, threshold: float | None = None) -> None:
        w = windows or DetectorWindows()
        self.fs = float(sample_rate_hz)
        self.highpass_hz = highpass_hz
        self.k_sigma = k_sigma
        self.refractory_s = w.refractory_s if w.refractory_s is not None else 0.25 / frequency_hz
        self.n_ctx = max(int(round(w.context_s * self.fs)), 16)
        self.n_warm = max(int(round(w.warmup_s * self.fs)), 4 * self.n_ctx)
        self.n_att = max(int(round(w.attribution_s * self.fs)), 4)
        self.n_iso = max(int(round(0.5 / frequency_hz * self.fs)), 8)
        self.threshold = threshold
        self._t = np.empty(0)
        self._u = np.empty(0)
        self._l = np.empty(0)
        self._done = 0          # samples of the buffer already scanned
        self._last_onset = -np.inf
        self.impacts: list[AccelImpact] = []

    def push_block(self, t_s, upper_ms2, lower_ms2) -> list[AccelImpact]:
        """Add samples (DAQ clock); returns the impacts that became final."""
        self._t = np.concatenate([self._t, np.asarray(t_s, float)])
        self._u = np.concatenate([self._u, np.asarray(upper_ms2, float)])
        self._l = np.concatenate([self._l, np.asarray(lower_ms2, float)])
        return self._scan(final=False)

    def finish(self) -> list[AccelImpact]:
        """End of data: scan the tail."""
        return self._scan(final=True)

    def _scan(self, final: bool) -> list[AccelImpact]:
        n = self._t.size
        if self.threshold is None:
            if n < self.n_warm and not final:
                return []
            hu = highpass(self._u, self.fs, self.highpass_hz)
            hl = highpass(self._l, self.fs, self.highpass_hz)
            s = np.abs(hu) + np.abs(hl)
            med = float(np.median(s))
            self.threshold = med + self.k_sigma * 1.4826 * float(np.median(np.abs(s - med)))
        end = n if final else n - self.n_ctx - self.n_iso
        if end <= self._done:
            return []
        lo = max(self._done - self.n_ctx, 0)
        hu = highpass(self._u[lo:], self.fs, self.highpass_hz)
        hl = highpass(self._l[lo:], self.fs, self.highpass_hz)
        s = np.abs(hu) + np.abs(hl)
        out = []
        for i in np.flatnonzero(s[self._done - lo:end - lo] > self.threshold) + (self._done - lo):
            t = self._t[lo + i]
            if t - self._last_onset < self.refractory_s:
                continue
            self._last_onset = t
            j = min(i + self.n_iso, s.size)
            out.append((i, j, t))
        # attribution window: up to the next onset (as in analyse_accel)
        made = []
        for m, (i, j, t) in enumerate(out):
            nxt = out[m + 1][0] if m + 1 < len(out) else self._next_onset(s, j, i)
            n_att = max(min(self.n_att, nxt - i), 1)
            made.append(_make_impact(t, hu[i:j], hl[i:j], n_att, self._u[lo + i:lo + j], self._l[lo + i:lo + j],
                                     self.fs))
        out = made
        self._done = end
        # keep a bounded buffer: context before the scan point is all the filter needs
        keep = max(self._done - 2 * self.n_ctx, 0)
        if keep > 0:
            self._t, self._u, self._l = self._t[keep:], self._u[keep:], self._l[keep:]
            self._done -= keep
        self.impacts += out
        return out

    def _next_onset(self, s: np.ndarray, j: int, i: int) -> int:
        """Index of the next above-threshold sample after the refractory time following onset i (or j)."""
        k0 = i + int(round(self.refractory_s * self.fs))
        above = np.flatnonzero(s[k0:j] > self.threshold) if k0 < j else np.empty(0, int)
        return int(k0 + above[0]) if above.size else j


def refine_clock_offset(accel_times_s, dic_times_s, seed_s: float, tol_s: float = 0.0005,
                        min_matched: int = MIN_MATCHED_IMPACTS) -> ClockOffset:
    """The clock relation refined from the offset ``seed_s`` (a live run's lab-clock stamps) as
    :func:`estimate_clock_offset` refines each candidate: the median of the differences of the impacts matched
    within ``tol_s``, twice, then offset + rate when the rate is significant. Determined with at least
    ``min_matched`` impacts matched; no search over other candidates (the seed already says which whole period
    is right)."""
    a = np.sort(np.asarray(accel_times_s, float))
    d = np.sort(np.asarray(dic_times_s, float))
    if a.size == 0 or d.size == 0:
        return ClockOffset(offset_s=float(seed_s), n_matched=0, residual_std_s=0.0, determined=False,
                           reason="no impact on one of the clocks yet", matched_span_s=None, n_accel=int(a.size),
                           n_dic=int(d.size))
    fit = _clock_fit(a, d, float(seed_s), tol_s)
    n = fit["n_matched"]
    if not n:
        fit["offset_s"] = float(seed_s)
    reason = "" if n >= min_matched else (f"only {n} impact(s) matched within {1e3 * tol_s:g} ms of the stamps' "
                                          f"offset {seed_s:+.6f} s, at least {min_matched} needed")
    return ClockOffset(**fit, determined=not reason, reason=reason, n_accel=int(a.size), n_dic=int(d.size),
                       assumption="seeded at the lab-clock stamps' offset")
