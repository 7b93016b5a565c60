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


@dataclass(kw_only=True)
class ClockOffset:
    """Camera-to-DAQ clock offset, t_daq = t_camera + offset_s, from ``n_matched`` impact pairs.

    ``determined`` is False when the matching cannot tell the offset (``reason`` says why: too few
    impacts in common, or another offset, typically a shaker period away, matching nearly as many);
    ``offset_s`` is then only the best candidate and must not be used (see :attr:`known_offset_s`).
    ``matched_span_s`` is the camera-clock interval of the matched DIC impacts (the overlap the offset
    rests on); ``candidates`` the other offsets tried, each (offset_s, n_matched), best first.
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

    @property
    def known_offset_s(self) -> float | None:
        """The offset when it is determined, else None."""
        return self.offset_s if self.determined else None

    def overlap_words(self) -> str:
        span = self.matched_span_s
        where = f" over t = {span[0]:.4f}..{span[1]:.4f} s (camera clock, {span[1] - span[0]:.3f} s)" if span else ""
        return (f"{self.n_matched} of {self.n_accel} accelerometer and {self.n_dic} DIC impacts matched{where}")

    def message(self) -> str:
        """One sentence for the user: the offset and the overlap it rests on, or why it is not determined."""
        if self.determined:
            extra = f" ({self.assumption})" if self.assumption else ""
            return f"clock offset t_daq - t_camera = {self.offset_s:+.5f} s from {self.overlap_words()}{extra}"
        return f"clock offset not determined: {self.reason}"

    def to_dict(self) -> dict:
        span = self.matched_span_s
        return {"determined": bool(self.determined), "offset_s": self.known_offset_s,
                "best_candidate_s": float(self.offset_s), "reason": self.reason or None,
                "n_matched": int(self.n_matched), "n_accel_impacts": int(self.n_accel),
                "n_dic_impacts": int(self.n_dic),
                "matched_span_s": [float(span[0]), float(span[1])] if span else None,
                "matched_duration_s": float(span[1] - span[0]) if span else 0.0,
                "candidates": [{"offset_s": float(o), "n_matched": int(n)} for o, n in self.candidates],
                "assumption": self.assumption or None,
                "message": self.message()}


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


def _match(a: np.ndarray, d: np.ndarray, off: float, tol_s: float) -> tuple[np.ndarray, np.ndarray]:
    """For offset ``off``: per DIC time, the signed distance (s) to the nearest accelerometer time on the
    camera clock, and the mask of those within ``tol_s``."""
    k = np.clip(np.searchsorted(a, d + off), 1, max(a.size - 1, 1))
    cand = np.stack([a[k - 1], a[np.minimum(k, a.size - 1)]]) - (d + off)
    r = cand[np.argmin(np.abs(cand), axis=0), np.arange(d.size)]
    return r, np.abs(r) <= tol_s


def _refine(a: np.ndarray, d: np.ndarray, off: float, tol_s: float) -> tuple[float, int, float]:
    """(offset, n_matched, residual std) after two median refinements from ``off``."""
    for _ in range(2):
        r, sel = _match(a, d, off, tol_s)
        if not sel.any():
            return off, 0, 0.0
        off += float(np.median(r[sel]))
    r, sel = _match(a, d, off, tol_s)
    return off, int(sel.sum()), float(np.std(r[sel])) if sel.sum() > 1 else 0.0


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
    """
    a = np.sort(np.asarray(accel_times_s, float))
    d = np.sort(np.asarray(dic_times_s, float))
    if a.size == 0 or d.size == 0:
        return None
    diffs = _differences_within(a, d, max_offset_s)
    if diffs.size == 0:
        return None
    seeds = _candidate_seeds(diffs, max_offset_s, tol_s)
    scored = [_refine(a, d, s, tol_s) for s in seeds]
    best = max(scored, key=lambda x: (x[1], -x[2]))
    if period_s:
        n_per = int(max_offset_s / period_s)
        scored += [_refine(a, d, best[0] + k * period_s, tol_s) for k in range(-n_per, n_per + 1) if k != 0
                   and abs(best[0] + k * period_s) <= max_offset_s]
    scored.sort(key=lambda x: (-x[1], x[2]))
    best = scored[0]
    off, n, sd = best
    if n == 0:
        return None
    others: list[tuple[float, int]] = []
    for o, m, _ in scored[1:]:
        if abs(o - off) > 3 * tol_s and all(abs(o - x) > 3 * tol_s for x, _ in others) and m > 0:
            others.append((float(o), int(m)))
    others = others[:5]
    r, sel = _match(a, d, off, tol_s)
    span = (float(d[sel][0]), float(d[sel][-1])) if sel.any() else None
    reason = ""
    slack, assumption = n - 1, ""
    if period_s and accel_span_s is not None and camera_span_s is not None:
        slack, assumption = _started_together(off, n, others, period_s, (accel_span_s, camera_span_s))
    rivals = [(o, m) for o, m in others if m >= slack]
    if n < min_matched:
        reason = (f"too little overlap: only {n} impact(s) in common between the accelerometers ({a.size}) and "
                  f"DIC ({d.size}), at least {min_matched} needed")
    elif rivals:
        o2, m2 = max(rivals, key=lambda x: x[1])
        shift = o2 - off
        per = f" ({shift / period_s:+.2f} shaker periods)" if period_s else ""
        reason = (f"ambiguous: offset {off:+.5f} s matches {n} impacts and {o2:+.5f} s{per} matches {m2}; "
                  "the overlap of the two records is too regular to tell them apart "
                  f"({a.size} accelerometer impacts, {d.size} DIC impacts)")
    return ClockOffset(offset_s=float(off), n_matched=int(n), residual_std_s=float(sd), determined=not reason,
                       reason=reason, matched_span_s=span, n_accel=int(a.size), n_dic=int(d.size),
                       candidates=others, assumption="" if reason else assumption)


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
    """The offset t_daq = t_camera + offset refined from ``seed_s`` (a live run's lab-clock stamps) as
    :func:`estimate_clock_offset` refines each candidate: the median of the differences of the impacts matched
    within ``tol_s``, twice. Determined with at least ``min_matched`` impacts matched; no search over other
    candidates (the seed already says which whole period is right)."""
    a = np.sort(np.asarray(accel_times_s, float))
    d = np.sort(np.asarray(dic_times_s, float))
    if a.size == 0 or d.size == 0:
        return ClockOffset(offset_s=float(seed_s), n_matched=0, residual_std_s=0.0, determined=False,
                           reason="no impact on one of the clocks yet", matched_span_s=None, n_accel=int(a.size),
                           n_dic=int(d.size))
    off, n, sd = _refine(a, d, float(seed_s), tol_s)
    _, sel = _match(a, d, off, tol_s)
    span = (float(d[sel][0]), float(d[sel][-1])) if sel.any() else None
    reason = "" if n >= min_matched else (f"only {n} impact(s) matched within {1e3 * tol_s:g} ms of the stamps' "
                                          f"offset {seed_s:+.6f} s, at least {min_matched} needed")
    return ClockOffset(offset_s=float(off) if n else float(seed_s), n_matched=int(n), residual_std_s=float(sd),
                       determined=not reason, reason=reason, matched_span_s=span, n_accel=int(a.size),
                       n_dic=int(d.size), assumption="seeded at the lab-clock stamps' offset")
