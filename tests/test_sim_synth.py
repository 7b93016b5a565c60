"""Synthetic rig: contract compliance, truth consistency, image fidelity, effects, CLI errors."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from vibro_io.accel import load_accel
from vibro_io.recording import open_recording
from vibro_sim.params import BallCavity
from vibro_sim.synth import SynthConfig, SynthError, parse_effect_args, synthesize, truth_path
from vibro_sim.synth.scenario import BASELINE_COR, build_models
from vibro_sim.synth.trajectory import regime, simulate_window

N_FRAMES = 200


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "rec"
    truth = synthesize(out, SynthConfig(frames=N_FRAMES, seed=5, clock_offset_s=3e-3), progress=False)
    return out, truth


def test_recording_follows_the_contract(rec):
    out, truth = rec
    r = open_recording(out)  # validates rig.yaml, frames and ROIs
    assert len(r.frames) == N_FRAMES
    assert sorted(p.name for p in out.iterdir()) == ["accel.csv", "frames", "rig.yaml"]
    tp = truth_path(out)
    assert tp.parent == out.parent and tp.is_file() and not (out / tp.name).exists()
    assert json.loads(tp.read_text())["schema"] == "vibro.truth/1"
    for key in ("effects", "structure", "frames", "impacts", "flights", "free_play_mm", "ball_offset_mm", "config"):
        assert key in truth
    assert r.rig.free_play_mm == pytest.approx(truth["free_play_mm"], abs=1e-12)
    assert BallCavity.from_rig(r.rig).free_play_m * 1e3 == pytest.approx(truth["free_play_mm"], abs=1e-12)
    acc = r.load_accel()
    assert acc.sample_rate_hz == pytest.approx(50_000.0, rel=1e-6)
    # both ROIs, carried by the true motion, stay inside the image in every frame
    mmpp = r.rig.camera.mm_per_px
    for key, roi in (("ball_mm", r.rig.dic.ball_roi), ("structure_mm", r.rig.dic.structure_roi)):
        pos = np.array(truth["frames"][key])
        rows = -(pos - pos[0]) / mmpp
        assert roi.y + rows.min() >= 0 and roi.y + roi.h + rows.max() <= 480, key
    # nothing in the recording names the hidden physics
    text = (out / "rig.yaml").read_text()
    for word in ("cor", "effect", "phase", "amplitude", "truth"):
        assert word not in text


def test_truth_impacts_lie_on_both_plates(rec):
    # Independent of the simulator: fit the exact parabola (-g t^2/2 + b t + c) of each
    # flight through the truth frames, evaluate it at the truth impact time and compare
    # with the cavity wall from the truth structure parameters. Frames are exact
    # (JSON keeps 17 digits), so only rounding remains: 1e-6 mm is generous.
    _, truth = rec
    t = np.array(truth["frames"]["t_s"])
    ball = np.array(truth["frames"]["ball_mm"])
    st = truth["structure"]
    w = 2 * math.pi * st["frequency_hz"]

    def ys(tt):
        return st["offset_mm"] + st["amplitude_mm"] * np.sin(w * tt + st["phase_rad"])
    b = truth["free_play_mm"]
    g_mm = 9.81e3
    plates = {i["plate"] for i in truth["impacts"]}
    assert plates == {"top", "bottom"}
    imps = truth["impacts"]
    checked = 0
    for a, c in zip(imps, imps[1:]):
        m = (t > a["t"]) & (t < c["t"])
        if m.sum() < 3:
            continue
        tt = t[m]
        y = ball[m] + 0.5 * g_mm * tt ** 2  # remove gravity, leaves a line
        p = np.polyfit(tt, y, 1)
        for imp in (a, c):
            y_imp = np.polyval(p, imp["t"]) - 0.5 * g_mm * imp["t"] ** 2
            wall = ys(imp["t"]) + (b if imp["plate"] == "top" else -b)
            assert abs(y_imp - wall) < 1e-6
            checked += 1
    assert checked > 10
    rel = ball - ys(t)
    assert np.all(np.abs(rel) <= b + 1e-9)
    assert truth["ball_offset_mm"] == pytest.approx(rel[0], abs=1e-9)


def _zncc(a, b):
    a = a - a.mean()
    b = b - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


def test_frames_correlate_at_the_true_displacement(rec):
    # The subset of frame 0 and the subset of frame k sampled (quintic spline) at the true
    # displacement differ only by noise: with signal variance s2 and read+quantisation
    # noise n2 = sigma^2 + 1/12 in each frame, E[ZNCC] = s2 / (s2 + n2) (0.997 here);
    # the interpolation of band-limited speckle (sigma 1.3 px) costs < 1e-3. Allow 0.003.
    out, truth = rec
    r = open_recording(out)
    mmpp = r.rig.camera.mm_per_px
    sub = r.rig.dic.subset_px
    frames = {f.index: f.image.astype(float) for f in r.frames if f.index in (0, 37, 81, 150)}
    n2 = 2.0 ** 2 + 1 / 12
    for key, roi in (("ball_mm", r.rig.dic.ball_roi), ("structure_mm", r.rig.dic.structure_roi)):
        pos = np.array(truth["frames"][key])
        r0, c0 = roi.y + roi.h // 2 - sub // 2, roi.x + roi.w // 2 - sub // 2
        ref = frames[0][r0:r0 + sub, c0:c0 + sub]
        s2 = ref.var() - n2
        expect = s2 / (s2 + n2)
        for k in (37, 81, 150):
            d_rows = -(pos[k] - pos[0]) / mmpp

            def at(shift):
                rr, cc = np.mgrid[0:sub, 0:sub].astype(float)
                return map_coordinates(frames[k], [rr + r0 + shift, cc + c0], order=5, mode="nearest")
            z_true = _zncc(ref, at(d_rows))
            assert z_true > expect - 0.003, (key, k, z_true, expect)
            # and the truth is the peak: 0.25 px off is clearly worse
            assert z_true > _zncc(ref, at(d_rows + 0.25)) and z_true > _zncc(ref, at(d_rows - 0.25))


def test_accel_bursts_follow_impacts_with_clock_offset(rec):
    # A burst starts at the impact on the DAQ clock = camera time + offset (3 ms): the
    # first sample exceeding 10 sigma of noise above the rigid acceleration must come
    # within a few samples (the modes start as sin, 20 us per sample) of t + offset.
    out, truth = rec
    r = open_recording(out)
    acc = load_accel(out / "accel.csv", r.rig.accelerometers)
    st = truth["structure"]
    w = 2 * math.pi * st["frequency_hz"]
    rigid = -st["amplitude_mm"] * 1e-3 * w ** 2 * np.sin(w * (acc.t_s - 3e-3) + st["phase_rad"])
    for imp in truth["impacts"][2:8]:
        sig = acc.upper_ms2 if imp["plate"] == "top" else acc.lower_ms2
        resid = np.abs(sig - rigid)
        after = np.flatnonzero((acc.t_s > imp["t"] + 3e-3 - 1e-3) & (resid > 5.0))
        assert after.size
        assert abs(acc.t_s[after[0]] - (imp["t"] + 3e-3)) < 5 * 2e-5
        # the plate that was hit rings harder than the other one (cross gain < 1)
        win = (acc.t_s > imp["t"] + 3e-3) & (acc.t_s < imp["t"] + 3e-3 + 2e-3)
        other = acc.lower_ms2 if imp["plate"] == "top" else acc.upper_ms2
        assert np.std((sig - rigid)[win]) > 2 * np.std((other - rigid)[win])


def _short(effects, **kw):
    cfg = SynthConfig(effects=effects, frames=300, seed=2, **kw)
    models = build_models(cfg, 0.4)
    return cfg, models, simulate_window(cfg, models)


def test_default_regime_is_two_alternating_impacts_per_cycle():
    cfg, _, traj = _short({})
    reg = regime(traj, cfg.frequency_hz)
    assert reg["alternating"] and reg["impacts_per_cycle"] == pytest.approx(2.0, abs=0.1)
    assert all(i.cor == BASELINE_COR for i in traj.impacts)


def test_tilt_lowers_flight_acceleration():
    tilt = 35.0
    _, _, traj = _short({"gravity_tilt": {"tilt_deg": tilt}})
    f = traj.flights[3]
    t = np.linspace(f.t_start_s, f.t_end_s, 9)[1:-1]
    a = 2 * np.polyfit(t, traj.result.sample(t), 2)[0]
    assert a == pytest.approx(-9.81 * math.cos(math.radians(tilt)), rel=1e-9)


@pytest.mark.parametrize("effect,param,law", [
    ("coulomb_friction", 3e-4, lambda v, p, m: -p * np.sign(v) / m),
    ("viscous_drag", 3e-4, lambda v, p, m: -p * v / m),
    ("quadratic_drag", 3e-4, lambda v, p, m: -p * v * np.abs(v) / m),
])
def test_flight_forces_follow_their_law(effect, param, law):
    key = {"coulomb_friction": "force_n", "viscous_drag": "coefficient_ns_per_m",
           "quadratic_drag": "coefficient_ns2_per_m2"}[effect]
    _, models, traj = _short({effect: {key: param}})
    m = models.cavity.mass_kg
    for f in traj.flights[2:6]:
        t = np.linspace(f.t_start_s, f.t_end_s, 13)[1:-1]
        v = traj.result.velocity(t)
        t, v = t[np.abs(v) > 1e-3], v[np.abs(v) > 1e-3]
        np.testing.assert_allclose(traj.result.acceleration(t), -9.81 + law(v, param, m), rtol=1e-9, atol=1e-9)


def test_asymmetric_restitution_means_and_scatter():
    # 300 frames ~ 6.6 cycles is too few; use 1500 frames (model only, fast): ~33 per plate,
    # the mean's standard error is 0.04 / sqrt(33) = 0.007 -> allow 3 SE = 0.021.
    cfg = SynthConfig(effects={"asymmetric_restitution": {}}, frames=1500, seed=4)
    traj = simulate_window(cfg, build_models(cfg, 1.0))
    for plate, mean in (("top", 0.6), ("bottom", 0.75)):
        e = np.array([i.cor for i in traj.impacts if i.plate == plate])
        assert e.size > 25
        assert e.mean() == pytest.approx(mean, abs=0.021)
        assert 0.025 < e.std() < 0.055  # sample std of ~33 draws of sigma 0.04: +-25 % at 2.5 sigma


def test_velocity_dependent_restitution_is_followed():
    _, _, traj = _short({"velocity_dependent_restitution": {"cor_at_zero": 0.9, "slope_s_per_m": 0.2}})
    for i in traj.impacts:
        assert i.cor == pytest.approx(0.9 - 0.2 * abs(i.v_rel_before_mps), abs=1e-12)


def test_structure_harmonics_are_in_the_truth_motion():
    _, models, traj = _short({"structure_harmonics": {"h2_ratio": 0.08, "h3_ratio": 0.03}})
    t = traj.frame_t_s
    w = models.structure.omega_rad_s
    cols = [np.ones_like(t)]
    for k in (1, 2, 3):
        cols += [np.sin(k * w * t), np.cos(k * w * t)]
    coef = np.linalg.lstsq(np.column_stack(cols), traj.structure_m, rcond=None)[0]
    amp = [math.hypot(coef[2 * k - 1], coef[2 * k]) for k in (1, 2, 3)]
    assert amp[1] / amp[0] == pytest.approx(0.08, rel=1e-9)
    assert amp[2] / amp[0] == pytest.approx(0.03, rel=1e-9)


def test_still_recording_does_not_move_and_drift_is_reported(tmp_path):
    out = tmp_path / "still"
    truth = synthesize(out, SynthConfig(frames=20, still=True, drift=True, tiff16=True, seed=1), progress=False)
    assert np.ptp(truth["frames"]["ball_mm"]) == 0 and np.ptp(truth["frames"]["structure_mm"]) == 0
    assert truth["impacts"] == []
    d = np.array(truth["camera_drift_mm"])
    assert d[0] == 0 and np.ptp(d) > 0
    img = cv2.imread(str(out / "frames" / "000000.tif"), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape == (480, 160)


def test_bad_configuration_is_refused_with_a_clear_message(tmp_path):
    with pytest.raises(SynthError, match="unknown effect 'wind'"):
        parse_effect_args(["wind"], None)
    with pytest.raises(SynthError, match="expected key=value"):
        parse_effect_args(["coulomb_friction"], ["force_n"])
    with pytest.raises(SynthError, match="not a number"):
        parse_effect_args(["coulomb_friction"], ["force_n=lots"])
    with pytest.raises(SynthError, match="add --effect gravity_tilt"):
        parse_effect_args(["coulomb_friction"], ["tilt_deg=5"])
    with pytest.raises(SynthError, match="must be in"):
        parse_effect_args(["asymmetric_restitution"], ["cor_top=1.5"])
    with pytest.raises(SynthError, match="at most one restitution"):
        parse_effect_args(["asymmetric_restitution", "velocity_dependent_restitution"], None)
    with pytest.raises(SynthError, match="frames"):
        SynthConfig(frames=1)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(SynthError, match="not empty"):
        synthesize(tmp_path / "full", SynthConfig(frames=3), progress=False)


def test_cli_reports_bad_input_in_one_line(tmp_path, capsys):
    from vibro_app.cli import main
    rc = main(["synth", "--out", str(tmp_path / "r"), "--effect", "gravity_tilt", "--param", "tilt_deg=abc"])
    err = capsys.readouterr().err
    assert rc == 2 and "tilt_deg=abc" in err and "Traceback" not in err
    rc = main(["synth", "--out", str(tmp_path / "r2"), "--frames", "12", "--no-progress",
               "--effect", "coulomb_friction", "--param", "force_n=1e-4"])
    assert rc == 0
    truth = json.loads(truth_path(tmp_path / "r2").read_text())
    assert truth["effects"] == [{"effect": "coulomb_friction", "parameters": {"force_n": 1e-4}}]
    assert len(list((tmp_path / "r2" / "frames").iterdir())) == 12
