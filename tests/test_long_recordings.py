"""Long recordings are analysed in memory linear in their length.

The tone search of the systematic-mismatch analysis (:mod:`vibro_discrepancy.systematic`) once built
frequencies x samples matrices (the grid has 2 x fps x T / (1/(4T)) ~ 2 N frequencies, so ~N^2: 6 GiB
per matrix at 20,000 frames); it now evaluates the grid by FFT and the 41 refining frequencies in
blocks. Checked here:

- the FFT grid and the blocked direct sums give the numbers of the whole-matrix sums to float rounding
  (uniform frames, dropped frames, times off the frame clock, times far from any clock), and the
  search's result (frequency, amplitude, fit) is the one of the former whole-matrix search;
- the clock offset's pairwise impact-time differences (accelerometer x DIC impacts) are taken only
  where they can pass (+-1 s): the same differences as the whole matrix;
- the peak memory (tracemalloc: every numpy array is traced) of the analysis after DIC (identify,
  replay, discrepancy, re-identification: ``vibro_app.analyze.analyze_recording`` on a given track,
  no report) of one synthetic recording, 1,500 frames then 4,500: linear growth triples it, quadratic
  growth (the former tone search: 145 MB at 1,500 frames, 1.6 GB at 5,000) gives ~9x. The assertion
  (< 5x) lies between them; the fixed part (rig, module state) only lowers the linear ratio.

The recording is the synthetic rig's physics with DIC emulated by white noise (tests/discrepancy_cases.py:
no frames rendered, a few seconds); the full-length sweep with ``vibro synth`` and ``vibro analyze`` is
bench/bench_length.py.
"""

from __future__ import annotations

import math
import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

from vibro_discrepancy.systematic import OVERSAMPLE, tone_drops_direct, tone_drops_grid, tone_search

SHORT, LONG = 1500, 4500
MAX_PEAK_RATIO = 5.0    # linear: ~3 (LONG / SHORT); quadratic: ~9


# ------------------------------------------------------------------ the periodogram, FFT vs direct sums
def _whole_matrix_periodogram(t, r, f_lo, f_hi, exclude_hz, width_hz):
    """The former search, frequencies x samples matrices at once (the reference)."""
    T = float(t.max() - t.min())
    grid = np.arange(f_lo, f_hi, 1.0 / (OVERSAMPLE * T))
    keep = np.ones(grid.size, bool)
    for f in exclude_hz:
        keep &= np.abs(grid - f) > width_hz
    grid = grid[keep]

    def drops(freqs):
        ph = 2 * np.pi * np.outer(freqs, t)
        C, S = np.cos(ph), np.sin(ph)
        C -= C.mean(axis=1, keepdims=True)
        S -= S.mean(axis=1, keepdims=True)
        cc, ss, cs = (C * C).sum(1), (S * S).sum(1), (C * S).sum(1)
        cr, sr = C @ r, S @ r
        det = cc * ss - cs ** 2
        a = (ss * cr - cs * sr) / det
        b = (cc * sr - cs * cr) / det
        return a * cr + b * sr, a, b, C, S

    d, *_ = drops(grid)
    j = int(np.nanargmax(d))
    step = 1.0 / (OVERSAMPLE * T)
    fine = np.linspace(grid[j] - step, grid[j] + step, 41)
    d2, a, b, C, S = drops(fine)
    m = int(np.nanargmax(d2))
    return float(d2[m]), a[m] * C[m] + b[m] * S[m], {"size": float(math.hypot(a[m], b[m])),
                                                      "frequency_hz": float(fine[m])}, d


def _series(kind: str, n: int = 1200, fps: float = 1000.0):
    rng = np.random.default_rng(7)
    t = np.arange(n) / fps
    if kind == "dropped frames":
        t = t[rng.random(n) > 0.15]
    elif kind == "off the clock":          # up to 0.4 frame from the frame clock (Taylor series, many terms)
        t = t + rng.uniform(-0.4, 0.4, n) / fps
    elif kind == "no clock":               # random times: the direct sums
        t = np.sort(rng.uniform(0.0, n / fps, n))
    elif kind == "late start":
        t = t + 1234.5
    r = (3e-6 * np.sin(2 * np.pi * 37.3 * t + 0.3) + 2e-6 * np.sin(2 * np.pi * 22.0 * t) + 1e-6
         + 1e-6 * rng.normal(size=t.size))
    return t, r


@pytest.mark.parametrize("kind", ["uniform", "dropped frames", "off the clock", "no clock", "late start"])
def test_fft_grid_equals_the_direct_sums(kind: str) -> None:
    """The grid's drops by FFT equal the whole-matrix sums within float rounding (1e-9 of the largest;
    measured ~1e-13), bins next to the Nyquist frequency aside (there the sine column vanishes and any
    evaluation is rounding: the former one too), and the blocked direct sums equal them too."""
    t, r = _series(kind)
    T = float(t.max() - t.min())
    step = 1.0 / (OVERSAMPLE * T)
    f_lo = 1.5 / T
    grid = np.arange(f_lo, 500.0, step)
    *_, ref = _whole_matrix_periodogram(t, r, f_lo, 500.0, [], 0.0)
    fft = tone_drops_grid(t, r, f_lo, step, grid.size)
    blocked = tone_drops_direct(t, r, grid, block=7 * t.size + 3)[0]   # blocks of 7 frequencies
    ok = grid < 500.0 - 2.0 / T
    scale = float(np.max(ref[ok]))
    assert np.max(np.abs(blocked[ok] - ref[ok])) <= 1e-12 * scale
    if kind == "late start":   # absolute times lose ~1e-13 s each in a float: compare on the same times
        ref = tone_drops_direct(t - t.min(), r, grid)[0]
    assert np.max(np.abs(fft[ok] - ref[ok])) <= 1e-9 * scale
    assert int(np.argmax(fft[ok])) == int(np.argmax(ref[ok]))


@pytest.mark.parametrize("kind", ["uniform", "dropped frames", "off the clock", "no clock"])
def test_tone_search_gives_the_former_result(kind: str) -> None:
    """tone_search (the structure analysis' band, drive harmonics left out) finds the frequency, the
    amplitude, the drop and the fit of the former whole-matrix search, to float rounding."""
    t, r = _series(kind)
    T = float(t.max() - t.min())
    drop, fit, info, _ = tone_search(t, r, 22.0, 1000.0)
    ref_drop, ref_fit, ref_info, _ = _whole_matrix_periodogram(t, r, 1.5 / T, 500.0,
                                                               [k * 22.0 for k in range(1, 6)], 1.0 / T)
    assert info["frequency_hz"] == pytest.approx(ref_info["frequency_hz"], rel=1e-12)
    assert abs(info["frequency_hz"] - 37.3) < 0.1
    assert info["size"] == pytest.approx(ref_info["size"], rel=1e-9)
    assert drop == pytest.approx(ref_drop, rel=1e-9)
    assert np.max(np.abs(fit - ref_fit)) <= 1e-9 * np.max(np.abs(ref_fit))


def test_direct_sums_memory_is_bounded_by_the_block() -> None:
    """The direct sums over 4,000 frequencies x 3,000 samples (96 MB a matrix at once) stay within a
    few blocks (1 Mi values, 8 MiB a float64 array): the peak is below 64 MB."""
    t, r = _series("uniform", n=3000)
    freqs = np.linspace(1.0, 499.0, 4000)
    tracemalloc.start()
    try:
        tone_drops_direct(t, r, freqs)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64e6, peak / 1e6


# ------------------------------------------------------------------ clock offset: pairs within reach
def test_clock_offset_pairs_are_those_of_the_whole_matrix() -> None:
    """The impact-time differences within +-max_offset_s, taken block by block, are those of the whole
    accelerometer x DIC matrix (the same multiset, so the same histogram and offset), including pairs at
    exactly +-max_offset_s."""
    from vibro_fit.accel_impacts import _differences_within

    rng = np.random.default_rng(5)
    d = np.sort(rng.uniform(0.0, 60.0, 2600))
    a = np.sort(np.concatenate([d[rng.random(d.size) > 0.1] + 0.0123, rng.uniform(0.0, 60.0, 50),
                                d[:3] + 1.0, d[3:5] - 1.0]))
    for max_offset_s in (1.0, 0.25, 100.0):
        whole = (a[:, None] - d[None, :]).ravel()
        whole = whole[np.abs(whole) <= max_offset_s]
        got = _differences_within(a, d, max_offset_s, rows=97)
        assert np.array_equal(np.sort(got), np.sort(whole))
    assert _differences_within(a[:0], d, 1.0).size == 0


# ------------------------------------------------------------------ the whole analysis, two lengths
@pytest.fixture(scope="module")
def long_case():
    from discrepancy_cases import make_case

    _, track, rig, _ = make_case({"coulomb_friction": {"force_n": 2e-4}}, seed=3, frames=LONG, cor_scatter=0.01)
    return track, rig


def _truncated(track, n: int):
    fields = {k: (v[:n] if isinstance(v, np.ndarray) and v.shape[:1] == (len(track),) else v)
              for k, v in vars(track).items()}
    return replace(track, **fields)


def _analysis_peak(track, rig, tmp_path, monkeypatch) -> tuple[float, dict]:
    """Peak traced memory (bytes above what was allocated before) of ``vibro analyze`` after DIC on
    ``track``: analyze_recording with the inputs handed over (no report)."""
    import vibro_app.analyze as A

    out = tmp_path / f"out{len(track)}"
    out.mkdir()
    monkeypatch.setattr(A, "load_inputs", lambda *a, **k: (rig, track, None))
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        doc = A.analyze_recording(tmp_path, out, progress=False, track_csv=tmp_path / "dic.csv", report=False)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    return peak, doc


def test_analysis_memory_grows_linearly_with_the_length(long_case, tmp_path, monkeypatch) -> None:
    track, rig = long_case
    short_peak, short_doc = _analysis_peak(_truncated(track, SHORT), rig, tmp_path, monkeypatch)
    long_peak, long_doc = _analysis_peak(track, rig, tmp_path, monkeypatch)
    for doc in (short_doc, long_doc):   # the whole analysis ran: impacts, a discrepancy block without error
        assert len(doc["impacts"]) > 20
        assert "error" not in doc["discrepancy"] and "skipped" not in doc["discrepancy"]
    ratio = long_peak / short_peak
    print(f"analysis peak: {short_peak / 1e6:.1f} MB at {SHORT} frames, {long_peak / 1e6:.1f} MB at {LONG} "
          f"(x{ratio:.2f}); {long_peak / LONG / 1e3:.1f} kB per frame")
    assert ratio < MAX_PEAK_RATIO, (f"peak {short_peak / 1e6:.1f} MB at {SHORT} frames, {long_peak / 1e6:.1f} MB "
                                    f"at {LONG}: x{ratio:.2f} for x{LONG / SHORT:.0f} the frames")
    assert long_peak / LONG < 20e3, f"{long_peak / LONG / 1e3:.1f} kB per frame"


# ------------------------------------------------------------------ the Hertz replay's contacts
def test_hertz_replay_keeps_no_dense_contact_solutions() -> None:
    """A Hertz replay keeps each contact's integration, not its dense solution (which cost ~100 kB per
    impact, 83 MB of a 20,000-frame replay): the result of a 1 s replay holds < 15 kB per impact
    (~5 kB: the closures, impacts and flight segments; was 95 kB), after a first run (imports, caches); a
    contact sampled later gives its dense solution then (the ball at the plate at contact entry, inside
    the plate during it)."""
    from vibro_model.kinematics import StructureKinematics
    from vibro_sim.forces import NoForce
    from vibro_sim.hertz_model import ContactSegment, HertzSolver
    from vibro_sim.params import BallCavity
    from vibro_sim.restitution import Constant

    S, cav = StructureKinematics(1.4e-3, 22.0, 0.3, 0.0), BallCavity()
    calibrated = HertzSolver(delta_a="calibrated")
    calibrated.simulate(S, cav, Constant(0.7), NoForce(), y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=0.1)
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        res = calibrated.simulate(S, cav, Constant(0.7), NoForce(), y0_m=0.0, v0_mps=0.0, t0_s=0.0, t_end_s=1.0)
        kept = tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()
    contacts = [s for s in res.segments if isinstance(s, ContactSegment)]
    assert len(res.impacts) > 30 and len(contacts) == len(res.impacts)
    assert kept / len(res.impacts) < 15e3, f"{kept / len(res.impacts) / 1e3:.1f} kB per impact"
    seg = contacts[5]
    side = 1.0 if seg.offset > 0 else -1.0
    plate = float(S.position(seg.t0)) + seg.offset
    assert seg.pos(seg.t0) == pytest.approx(plate, abs=1e-12)
    assert side * (seg.pos(seg.t0 + 5e-6) - float(S.position(seg.t0 + 5e-6)) - seg.offset) > 0   # penetrates
