"""Issue 38, item 1: a structure model that follows the drive.

A shaker under closed-loop control need not hold one amplitude over a take. The synthetic rig's ``drive_change``
(an amplitude step and a linear frequency drift, :class:`vibro_model.kinematics.DriveChange`) must be exact
kinematics; the identification's windowed drive (:mod:`vibro_fit.drive`) must say whether the drive held still,
with both a statistical and a physical floor, and by how much and when it moved; a stationary drive keeps the
global sine untouched; and the discrepancy analysis must not take the drive changing for a structure tone.

Tolerances: the windowed fits' own sigmas (white noise of a known sigma on pure signals; the recording's DIC noise
end to end), the step's time within one window (the windows are what resolves it), and the physical floors of
:mod:`vibro_fit.drive` (0.5 % of the amplitude, 5 mrad of phase).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vibro_fit import drive as drv
from vibro_fit.structure_fit import fit_structure
from vibro_model.kinematics import DriveChange, StructureKinematics

ROOT = Path(__file__).resolve().parents[1]
VIBRO = [sys.executable, "-m", "vibro_app.cli"]
FPS = 1000.0
A0_MM = 1.41                 # the rig's default drive: 27 m/s^2 at 22 Hz
F0_HZ = 22.0
SIGMA_MM = 5e-4              # white noise of the pure signals (0.5 um: a few times the DIC structure noise)


def _track(n: int, seed: int, sigma_mm: float = SIGMA_MM, **change) -> tuple[np.ndarray, np.ndarray]:
    """A structure track (mm) of ``n`` frames from DriveChange (its parameters in ``change``) plus white noise."""
    S = DriveChange(A0_MM, F0_HZ, 0.7, 0.05, **change)
    t = np.arange(n) / FPS
    return t, np.asarray(S.position(t)) + np.random.default_rng(seed).normal(0.0, sigma_mm, n)


def _drive(t: np.ndarray, y: np.ndarray) -> drv.DriveModel:
    return drv.fit_drive(t, y, fit_structure(t, y))


# ------------------------------------------------------------------ the kinematics
def test_drive_change_kinematics_are_exact_and_bounded() -> None:
    """Velocity, acceleration and jerk are the derivatives of the position (central differences at 10 us: their
    error ~ h^2 |Y'''| / 6, 1e-6 relative), the bounds hold over the horizon, and without a change the class is
    the plain sine to rounding (the harmonics included)."""
    S = DriveChange(1.4e-3, 22.0, 0.3, 0.0, 0.05, 0.02, 0.5, -0.8, step_ratio=0.1, step_time_s=0.5, ramp_s=0.05,
                    drift_hz_per_s=0.3, horizon_s=3.0)
    t = np.linspace(-1.0, 2.0, 300_001)
    h = 1e-6
    for order, f in enumerate((S.position, S.velocity, S.acceleration)):
        g = (S.velocity, S.acceleration, S.jerk)[order]
        num = (np.asarray(f(t + h)) - np.asarray(f(t - h))) / (2 * h)
        exact = np.asarray(g(t))
        assert np.max(np.abs(num - exact)) < 1e-6 * np.max(np.abs(exact)), order
        assert np.max(np.abs(exact)) <= S.bound(order + 1)
    # the amplitude steps by the ratio (2 % .. 98 % within the ramp) and the frequency drifts
    assert S.amplitude_at(-1.0) == pytest.approx(1.4e-3, rel=1e-9)
    assert S.amplitude_at(1.9) == pytest.approx(1.54e-3, rel=1e-9)
    lo, hi = S.amplitude_at(0.5 - 0.025), S.amplitude_at(0.5 + 0.025)
    assert 0.01 < (lo - 1.4e-3) / 1.4e-4 < 0.03 and 0.97 < (hi - 1.4e-3) / 1.4e-4 < 0.99
    assert S.frequency_at(1.0) == pytest.approx(22.3)
    plain = StructureKinematics(1.4e-3, 22.0, 0.3, 0.0, 0.05, 0.02, 0.5, -0.8)
    same = DriveChange(**plain.to_dict())
    for n in range(4):
        assert np.max(np.abs(plain._sum(t, n) - same._sum(t, n))) <= 1e-12 * plain.bound(n)


def test_synth_drive_change_is_refused_with_a_tone_and_states_its_parameters_in_the_truth() -> None:
    from vibro_sim.synth import SynthConfig, SynthError, parse_effect_args
    from vibro_sim.synth.scenario import build_models, effects_truth

    eff = parse_effect_args(["drive_change"], ["amplitude_step_ratio=0.1", "frequency_drift_hz_per_s=0.01"])
    cfg = SynthConfig(effects=eff, frames=100)
    S = build_models(cfg, 0.3).structure
    assert isinstance(S, DriveChange) and S.step_ratio == 0.1 and S.drift_hz_per_s == 0.01
    row = effects_truth(cfg)[0]
    assert row["effect"] == "drive_change" and row["parameters"]["amplitude_step_ratio"] == 0.1
    assert row["expected_finding"] == "none" and row["expected_section"] == "drive"
    with pytest.raises(SynthError, match="drive_change"):
        SynthConfig(effects={"drive_change": {}, "structure_tone": {}}, frames=10)
    with pytest.raises(SynthError, match="0 Hz"):
        SynthConfig(effects={"drive_change": {"frequency_drift_hz_per_s": -1.0}}, frames=30_000)


# ------------------------------------------------------------------ the windowed drive on pure signals
def test_stationary_drive_is_stationary() -> None:
    """No change, white noise, 12 takes of 4 s: each test's family-wise false-alarm probability is 1e-3, so even
    one false alarm in 24 tests has probability ~2 %; the global sine is what fit_structure gives."""
    for seed in range(12):
        t, y = _track(4000, seed)
        d = _drive(t, y)
        assert d.stationary is True, (seed, d.amplitude, d.phase)
        assert d.warning() is None and d.to_dict()["stationary"] is True
        assert abs(len(d.windows) - 4.0 / d.window_s) < 1   # every window filled to at least half


def test_amplitude_step_is_found_with_its_size_and_time() -> None:
    """A 10 % step at 2 s (ramp 0.1 s): not stationary, the change within 4 of its sigmas of the truth, the time
    within one window; the phase has not moved."""
    t, y = _track(4000, 3, step_ratio=0.1, step_time_s=2.0, ramp_s=0.1)
    d = _drive(t, y)
    a = d.amplitude
    assert d.stationary is False and a.changed and not d.phase.moved
    assert abs(a.change_mm - 0.1 * A0_MM) < 4 * a.change_std_mm, a
    assert abs(a.t_s - 2.0) < d.window_s, a
    assert a.t_between_s[0] - d.window_s < 2.0 < a.t_between_s[1] + d.window_s
    assert "amplitude changed by +10.0 %" in d.warning()


def test_the_two_floors() -> None:
    """Physical floor: a 0.2 % step is tens of sigmas here but below 0.5 % of the amplitude: stationary.
    Statistical floor: a 1 % step in 0.3 mm of noise (the step's sigma ~1 % of the amplitude) is not significant:
    stationary. The same 1 % step in the quiet track is reported."""
    t, y = _track(4000, 4, step_ratio=0.002, step_time_s=2.0)
    d = _drive(t, y)
    assert d.stationary is True and abs(d.amplitude.z) > 10, d.amplitude
    t, y = _track(4000, 5, sigma_mm=0.3, step_ratio=0.01, step_time_s=2.0)
    d = _drive(t, y)
    assert d.stationary is True and 0.01 * A0_MM < 3 * d.amplitude.change_std_mm, d.amplitude
    t, y = _track(4000, 6, step_ratio=0.01, step_time_s=2.0)
    assert _drive(t, y).stationary is False


def test_slow_frequency_drift_is_found() -> None:
    """0.02 Hz/s over 4 s (22.00 -> 22.08 Hz; the phase strays ~0.1 rad from one sine): the phase moved, the drift
    within 4 of its sigmas, the windows refitted at their local frequency (4 sigmas), the amplitude unchanged."""
    t, y = _track(4000, 7, drift_hz_per_s=0.02)
    d = _drive(t, y)
    p = d.phase
    assert d.stationary is False and p.moved and not d.amplitude.changed, (p, d.amplitude)
    assert abs(p.drift_hz_per_s - 0.02) < 4 * p.drift_std_hz_per_s, p
    for w in d.windows:
        assert abs(w.frequency_hz - (F0_HZ + 0.02 * w.t_s)) < 4 * w.frequency_std_hz + 1e-4, w
    assert "frequency drift" in d.warning()


def test_too_short_is_not_tested() -> None:
    t, y = _track(200, 8)
    d = _drive(t, y)
    assert d.stationary is None and "windows" in d.reason and d.warning() is None


# ------------------------------------------------------------------ end to end: vibro synth + vibro analyze
def _run(*args: str, cwd: Path) -> None:
    out = subprocess.run([*VIBRO, *args], capture_output=True, text=True, timeout=300, cwd=cwd)
    assert out.returncode == 0, out.stderr[-3000:]


@pytest.fixture(scope="module")
def analysed(tmp_path_factory) -> dict:
    """A 2 s take with a +10 % drive step at 1.0 s, and a stationary 1.5 s take (the baseline: 8 windows)."""
    tmp = tmp_path_factory.mktemp("drive")
    cases = {"step": ["--frames", "2000", "--seed", "21", "--effect", "drive_change",
                      "--param", "amplitude_step_ratio=0.1", "--param", "amplitude_step_time_s=1.0"],
             "still": ["--frames", "1500", "--seed", "22"]}
    out = {}
    for name, args in cases.items():
        rec = tmp / name
        _run("synth", "--out", str(rec), *args, "--no-progress", cwd=tmp)
        _run("analyze", str(rec), "--out", str(tmp / f"{name}.out"), "--no-report", "--no-progress", cwd=tmp)
        out[name] = (json.loads((tmp / f"{name}.out" / "results.json").read_text()),
                     json.loads((tmp / f"{name}.truth.json").read_text()), tmp / f"{name}.out")
    return out


def test_drive_step_is_reported_not_stationary(analysed) -> None:
    doc, truth, _ = analysed["step"]
    params = next(e for e in truth["effects"] if e["effect"] == "drive_change")["parameters"]
    assert params["amplitude_step_ratio"] == 0.1 and params["amplitude_step_time_s"] == 1.0
    d = doc["drive"]
    assert d["stationary"] is False and d["tested"] is True
    a = d["amplitude"]
    true_change = params["amplitude_step_ratio"] * truth["structure"]["amplitude_mm"]
    assert abs(a["change_mm"] - true_change) < 4 * a["change_std_mm"] + 1e-3 * true_change, (a, true_change)
    assert abs(a["t_s"] - params["amplitude_step_time_s"]) < d["window_s"], a
    assert d["phase"]["moved"] is False
    assert any("drive is not stationary" in w for w in doc["warnings"])
    for row in d["windows"]:
        assert set(row) >= {"t_s", "amplitude_mm", "amplitude_std_mm", "phase_rad", "phase_std_rad",
                            "frequency_hz", "offset_mm"}


def test_drive_step_is_not_a_structure_tone(analysed) -> None:
    """No modelled tone, no located periodic structure pattern near the drive, no structure harmonics: one
    ``drive`` pattern says what the drive did."""
    from vibro_discrepancy.tone import TONE_PARAMETERS, modelled_tone

    doc, _, _ = analysed["step"]
    disc = doc["discrepancy"]
    effects = [f["effect"] for f in disc["findings"]]
    assert "structure_harmonics" not in effects, disc["findings"]
    assert not any(modelled_tone(f) for f in disc["findings"]), disc["findings"]
    for f in disc["findings"]:
        assert not any(k in (f.get("parameters") or {}) for k in TONE_PARAMETERS)
        mism = (f.get("details") or {}).get("mismatches", [])
        near = [m for m in mism if m["series"] == "structure" and m["shape"] == "periodic"
                and abs(m["frequency_hz"] - F0_HZ) < 0.25 * F0_HZ]
        assert near == [], near
        drive = [m for m in mism if m["shape"] == "drive"]
        if drive:
            assert "not a structure tone" in drive[0]["words"] and "+10.0 %" in drive[0]["words"]
        # the COR computed with the drive-following structure velocity shows no step at the drive's change
        assert not any(m["series"] == "cor" and m["shape"] == "step" for m in mism), mism


def test_stationary_take_keeps_the_global_sine(analysed) -> None:
    """``stationary: true``, no warning about the drive, and the structure section is the global sine of the
    track (fit_structure on dic.csv, as before the drive model existed; the recordings of the issue gave
    identical results.json numbers before and after it, the ``drive`` section added)."""
    from vibro_io.dic_bias import track_as_identified
    from vibro_io.dictrack import read_dic_csv

    doc, _, out = analysed["still"]
    assert doc["drive"]["stationary"] is True and doc["drive"]["amplitude"]["changed"] is False
    assert not any("drive" in w for w in doc["warnings"])
    # the track as identified: dic.csv with the sub-pixel bias the identification took out (vibro_io.dic_bias)
    tr = track_as_identified(read_dic_csv(out / "dic.csv"), doc.get("dic_bias"))
    g = fit_structure(tr.t_s[tr.good], tr.structure_mm[tr.good])
    s = doc["structure"]
    # dic.csv holds the track rounded to its printed digits: the same fit to far below its own sigmas
    for key, std in (("amplitude_mm", "amplitude_std_mm"), ("frequency_hz", "frequency_std_hz"),
                     ("phase_rad", "phase_std_rad"), ("offset_mm", "offset_std_mm")):
        assert abs(s[key] - getattr(g, key)) < 1e-3 * s[std], key
    assert math.isclose(doc["drive"]["global"]["amplitude_mm"], s["amplitude_mm"])
