"""Accelerometer impacts: detection, plate, clipping, spectrum peaks, clock offset, refinement."""

from __future__ import annotations

import numpy as np
import pytest

from vibro_fit.accel_impacts import analyse_accel, estimate_clock_offset, find_clipping, highpass
from vibro_fit.identify import identify
from vibro_fit.synthetic import accel_signals, paper_rig, sample_track, simulate
from vibro_model.errors import AccelError

FS = 50_000.0


@pytest.fixture(scope="module")
def truth():
    return simulate(amplitude_m=3e-3, duration_s=0.62, cor_jitter=0.02, seed=4)


def test_highpass_removes_excitation_keeps_ringing():
    # 4th-order Butterworth at 100 Hz, applied forward-backward (8th order magnitude): a 22 Hz sine
    # is attenuated by (22/100)^8 ~ 5e-6; a 3 kHz tone passes within 1e-3.
    t = np.arange(int(0.5 * FS)) / FS
    lo = highpass(np.sin(2 * np.pi * 22 * t), FS)
    x = np.sin(2 * np.pi * 3000 * t)
    hi = highpass(x, FS)
    mid = slice(5000, -5000)   # away from the edge transients
    assert np.max(np.abs(lo[mid])) < 1e-4
    # gain (RMS ratio; the sampled peaks of a 3 kHz tone at 50 kHz miss the crest by up to 2 %)
    assert np.sqrt(np.mean(hi[mid] ** 2) / np.mean(x[mid] ** 2)) == pytest.approx(1.0, abs=1e-3)
    with pytest.raises(AccelError, match="cut-off"):
        highpass(lo, FS, cutoff_hz=30_000)


def test_detection_plate_and_spectrum(truth):
    acc = accel_signals(truth, fs_hz=FS, duration_s=0.6, offset_s=0.0)
    res = analyse_accel(acc, 22.0)
    true_t = np.array([i.t_s for i in truth.impacts if 0.001 < i.t_s < 0.59])
    got = np.array([i.t_s for i in res.impacts])
    assert got.size == true_t.size
    # onset = first sample above 8 sigma of a 300 m/s^2 ringing starting at sin(0): within 0.1 ms
    assert np.max(np.abs(got - true_t)) < 1e-4
    plates = [i.plate for i in truth.impacts if 0.001 < i.t_s < 0.59]
    assert [i.plate for i in res.impacts] == plates
    # averaged spectrum: the two ringing modes (3100 and 7400 Hz) are the main peaks; half-period
    # segments (22.7 ms) give a 44 Hz resolution
    assert any(abs(p - 3100) < 100 for p in res.peaks_hz)
    assert any(abs(p - 7400) < 100 for p in res.peaks_hz)
    assert not res.clipping
    # per impact: the ringing's first mode among its main peaks; energy sum(a^2) dt of the decaying
    # sine pair 300 e^(-t/tau) (sin w1 t + 0.6 sin w2 t) over the 2 ms window (tau = 2 ms):
    # (300^2 / 2)(1 + 0.36) (tau / 2)(1 - e^-2) ~ 53 (m/s^2)^2 s on the hit plate (cross terms average out)
    for imp in res.impacts:
        assert any(abs(f - 3100) < 100 for f in imp.dominant_frequencies_hz)
        assert not imp.clipped
        e_hit = imp.energy_upper if imp.plate == "top" else imp.energy_lower
        assert e_hit == pytest.approx(0.5 * 300 ** 2 * 1.36 * 0.001 * (1 - np.exp(-2)), rel=0.1)


def test_clipping_is_reported_with_channel_and_time(truth):
    acc = accel_signals(truth, fs_hz=FS, duration_s=0.6, clip_mps2=150.0)
    res = analyse_accel(acc, 22.0)
    assert res.clipping and all(c["channel"] == "upper" for c in res.clipping)
    assert any("upper" in w and "clipped" in w and "t =" in w for w in res.warnings)
    assert any(i.clipped for i in res.impacts if i.plate == "top")
    # a plain noisy signal has no flat run at its extremes
    rng = np.random.default_rng(0)
    assert find_clipping(np.arange(1000) / FS, rng.standard_normal(1000), "lower") == []


def test_clock_offset_recovered():
    # DAQ clock 12.3 ms ahead of the camera: recovered to the onset latency (< 0.1 ms)
    truth = simulate(amplitude_m=3e-3, duration_s=1.0, seed=4)
    acc = accel_signals(truth, fs_hz=FS, duration_s=0.95, offset_s=0.0123)
    res = analyse_accel(acc, 22.0)
    cam = [i.t_s for i in truth.impacts if 0.02 < i.t_s < 0.9]
    off = estimate_clock_offset([i.t_s for i in res.impacts], cam)
    assert off is not None and off.n_matched >= len(cam) - 1
    assert off.offset_s == pytest.approx(0.0123, abs=1e-4)


def test_identify_with_accelerometers_reports_offset_and_keeps_cors(truth):
    rig = paper_rig(accelerometers=True)
    track = sample_track(truth, n_frames=600, noise_mm=0.0005)
    acc = accel_signals(truth, fs_hz=FS, duration_s=0.6, offset_s=-0.004)
    ident = identify(track, rig, accel=acc)
    ref = identify(track, paper_rig())
    assert ident.clock_offset is not None
    assert ident.clock_offset.offset_s == pytest.approx(-0.004, abs=1e-4)
    # the accelerometer times fall between the same two frames as DIC's contact frames: same CORs
    assert len(ident.impacts) == len(ref.impacts)
    assert np.allclose([i.cor for i in ident.impacts], [i.cor for i in ref.impacts], atol=1e-9)


def test_block_detector_matches_batch(truth):
    # streamed in 10 ms blocks, with 30 ms of filter context each side, the detector must find the
    # same onsets as the whole-record analysis to within a few samples (the zero-phase filter's edge
    # transient decays over ~3 time constants of 1/(2 pi 100 Hz); different thresholds estimates)
    from vibro_fit.accel_impacts import AccelImpactDetector

    acc = accel_signals(truth, fs_hz=FS, duration_s=0.6)
    batch = analyse_accel(acc, 22.0)
    det = AccelImpactDetector(FS, 22.0)
    got = []
    for k in range(0, acc.t_s.size, 500):
        got += det.push_block(acc.t_s[k:k + 500], acc.upper_ms2[k:k + 500], acc.lower_ms2[k:k + 500])
    got += det.finish()
    assert len(got) == len(batch.impacts)
    assert np.max(np.abs(np.array([i.t_s for i in got]) - [i.t_s for i in batch.impacts])) <= 5 / FS
    assert [i.plate for i in got] == [i.plate for i in batch.impacts]
