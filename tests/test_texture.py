"""Real footage: the texture check (SSSIG against the noise), the correlation quality along the track, and the
synthetic unspeckled shiny ball (tracked within the accuracy its texture and noise predict, or refused).

Tolerances: a track's error against the truth is the noise propagated through the correlation (predicted by
the texture check, scaled to the synthetic rig's TRUE noise) plus the 6-tap interpolant's bias, which
test_dic_accuracy.py bounds at 0.005 px. For N ~ 150 Gaussian errors of std s the RMS lies within
1 +- 3/sqrt(2N) = +-17 % of s and the largest |error| below ~3.5 s: bounds 1.5 s and 5 s leave margin.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from vibro_app.cli import main as vibro
from vibro_dic.quality import TrackQuality, TrackQualityError
from vibro_dic.speckle import speckle_pattern
from vibro_dic.texture import TextureError, assess_texture, noise_from_frames, noise_from_image
from vibro_dic.tracker import MeshResult, track_recording
from vibro_io.dictrack import read_dic_csv
from vibro_io.recording import open_recording
from vibro_io.rig import DicConfig, Roi
from vibro_sim.synth import SynthConfig, synthesize

FRAMES = 150
NOISE_GRAY = 2.0
TRUE_NOISE = math.sqrt(NOISE_GRAY ** 2 + 1.0 / 12.0)  # read noise + 8-bit rounding (uniform, 1/12 gray^2)
INTERP_BIAS_PX = 0.005  # test_dic_accuracy.test_six_tap_interpolant_has_less_bias_than_bicubic


def _synth(tmp_path_factory, name: str, **kw):
    out = tmp_path_factory.mktemp(name) / "rec"
    truth = synthesize(out, SynthConfig(frames=FRAMES, accel=False, noise_gray=NOISE_GRAY, **kw), progress=False)
    return out, truth


@pytest.fixture(scope="module")
def speckled(tmp_path_factory):
    return _synth(tmp_path_factory, "speckled")


@pytest.fixture(scope="module")
def shiny(tmp_path_factory):
    """Unspeckled dark glossy ball, light 30 deg from the camera axis: the highlight is on the ball's ROI."""
    return _synth(tmp_path_factory, "shiny", ball_surface="shiny", light_deg=30.0)


@pytest.fixture(scope="module")
def shiny_side_lit_jpeg(tmp_path_factory):
    """Unspeckled ball lit from 110 deg (highlight near the top limb, outside the ROI), JPEG quality 75."""
    return _synth(tmp_path_factory, "shiny_jpeg", ball_surface="shiny", light_deg=110.0, jpeg_quality=75)


def _errors_px(rec, truth, rows):
    s = truth["image"]["mm_per_px"]
    out = {}
    for body in ("ball", "structure"):
        x = np.asarray(truth["frames"][f"{body}_mm"])
        m = np.array([getattr(r, f"{body}_mm") for r in rows])
        out[body] = (m - (x - x[0])) / s
    return out


# --- noise and texture, on images with known noise --------------------------------------------------------
def test_noise_from_frames_finds_the_static_part_and_ignores_motion() -> None:
    rng = np.random.default_rng(3)
    pat = speckle_pattern((128, 256), seed=4)
    sigma = 3.0
    a, b = pat.render(), pat.render(0.0, 1.7)  # the speckle moves 1.7 px between the frames
    a[:, :128] = b[:, :128] = 90.0             # the left half is a static, flat background
    a = a + rng.normal(0, sigma, a.shape)
    b = b + rng.normal(0, sigma, b.shape)
    est = noise_from_frames(a, b)
    # 32 static 16x16 blocks, 8192 px: the pooled std is within ~1 % (1/sqrt(2 * 8192)); 5 % is 6 SE
    assert est.sigma_gray == pytest.approx(sigma, rel=0.05)
    assert est.n_pixels >= 32 * 256 * 0.9


def test_a_roi_of_pure_noise_is_refused_with_its_numbers_and_speckle_passes() -> None:
    rng = np.random.default_rng(5)
    sigma = 3.0  # gray-level std 3 > the tracker's old MIN_SUBSET_STD of 2: noise alone used to pass as texture
    img = np.full((160, 320), 60.0)
    img[:, 160:] = speckle_pattern((160, 160), seed=6).render()
    frame0 = img + rng.normal(0, sigma, img.shape)
    frame1 = img + rng.normal(0, sigma, img.shape)
    dic = DicConfig(subset_px=31, mesh_step_px=10, ball_roi=Roi(40, 40, 61, 61), structure_roi=Roi(200, 40, 81, 61))
    noise = noise_from_frames(frame0, frame1)
    report = assess_texture(frame0, dic, noise)
    ball, structure = report.bodies["ball"], report.bodies["structure"]
    # the noise's own gradient energy: n_px * 130/144 * sigma^2 = 961 * 0.903 * 9 = 7808 gray^2; the measured SSSIG of
    # a flat subset scatters about it by ~sqrt(2 / 961) relative (a few %), the signal part is ~0: unusable
    assert np.median(ball.sssig) == pytest.approx(961 * 130 / 144 * sigma ** 2, rel=0.1)
    assert ball.n_usable == 0 and structure.n_usable == len(structure.points)
    with pytest.raises(TextureError) as exc:
        report.check()
    msg = str(exc.value)
    assert "dic.ball_roi [40, 40, 61, 61]" in msg and "SSSIG" in msg and "0.05 px" in msg
    assert f"{noise.sigma_gray:.3g} gray levels" in msg and "structure_roi" not in msg
    # speckle of std 45 and 1.5 px blur: SSSIG ~1e5 gray^2 per axis, sigma = sqrt(2) 3 / sqrt(1e5) ~ 0.013 px
    assert np.all(structure.sigma_px < 0.05)


def test_one_frame_noise_is_an_upper_bound_on_speckle() -> None:
    rng = np.random.default_rng(7)
    img = speckle_pattern((128, 128), seed=8).render() + rng.normal(0, 2.0, (128, 128))
    assert noise_from_image(img).sigma_gray >= 2.0 * 0.95


# --- correlation quality: the accumulator on tracker results ---------------------------------------------
def _mesh(zncc: float, valid: list[bool], lost: bool = False) -> MeshResult:
    n = len(valid)
    return MeshResult(name="ball", u_px=np.zeros(2) if not lost else np.full(2, np.nan), valid=sum(valid), zncc=zncc,
                      lost=lost,
                      point_valid=np.array(valid), point_zncc=np.full(n, zncc), point_u_px=np.zeros((n, 2)))


def test_track_quality_counts_low_zncc_lost_frames_and_lost_subsets() -> None:
    q = TrackQuality(zncc_warn=0.9, max_lost_fraction=0.5)
    zs = [0.99, 0.95, 0.85, 0.97, 0.80]
    for k, z in enumerate(zs):
        q.add(k, {"ball": _mesh(z, [True, True, k < 2, True])})  # subset 2 kept in 2 of 5 frames
    q.add(5, {"ball": _mesh(math.nan, [False] * 4, lost=True)})
    q.add(6, {})  # image missing
    b = q.summary()["bodies"]["ball"]
    assert b["frames"] == 7 and b["frames_lost"] == 2 and b["first_lost"] == [5, 6]
    assert b["zncc_median"] == pytest.approx(float(np.median(zs))) and b["zncc_min"] == pytest.approx(0.80)
    assert b["frames_below_zncc_warn"] == 2 and b["first_below"] == [2, 4]
    assert b["subsets_lost"] == [2]
    warnings = q.check()
    assert any("below 0.9 in 2 of 5" in w for w in warnings) and any("lost in 2 of 7" in w for w in warnings)
    for k in range(7, 12):
        q.add(k, {})
    with pytest.raises(TrackQualityError, match=r"ball lost in 7 of 12 frames \(58% > 50%"):
        q.check()


def test_a_body_lost_after_it_turned_is_refused_saying_it_spins() -> None:
    for turn_deg, hint in ((12.0, True), (0.4, False)):
        q = TrackQuality(max_lost_fraction=0.5)
        for k in range(4):
            m = _mesh(0.95, [True] * 4)
            q.add(k, {"ball": replace(m, rot_rad=math.radians(turn_deg) * (k + 1) / 4)})
        for k in range(4, 12):
            q.add(k, {"ball": _mesh(math.nan, [False] * 4, lost=True)})
        assert q.summary()["bodies"]["ball"]["rotation_at_first_loss_deg"] == pytest.approx(turn_deg)
        with pytest.raises(TrackQualityError) as err:
            q.check()
        assert ("it spins" in str(err.value)) is hint and ("ball_method: outline" in str(err.value)) is hint


def test_a_rendered_spinning_ball_is_refused_saying_it_spins(tmp_path, capsys) -> None:
    rec = tmp_path / "spin"
    synthesize(rec, SynthConfig(frames=300, seed=1, accel=False, spin_rad_s=2.0), progress=False)
    rc, cap = _analyze(rec, tmp_path / "out", capsys)
    assert rc != 0 and "Traceback" not in cap.err
    assert "tracking refused: ball lost" in cap.err and "it spins" in cap.err, cap.err[-800:]


def test_a_correlation_of_one_to_rounding_reads_as_no_residual_noise() -> None:
    # A subset that matches its reference exactly (the reference frame itself) can come out at ZNCC 1 + 1e-12.
    # The residual noise sqrt((1 - ZNCC) V) is then 0, not the square root of a negative number: this crashed the
    # tracker node's diagnostics timer when its first report came after such frames only.
    img = speckle_pattern((80, 80), seed=3).render()
    dic = DicConfig(subset_px=31, mesh_step_px=10, ball_roi=Roi(10, 10, 41, 41), structure_roi=Roi(10, 10, 41, 41))
    q = TrackQuality()
    q.texture = assess_texture(img, dic, noise_from_image(img))
    n = len(q.texture.bodies["ball"].points)
    for k in range(3):
        q.add(k, {"ball": _mesh(1.0 + 1e-12, [True] * n)})
    b = q.summary()["bodies"]["ball"]
    assert b["zncc_median"] == pytest.approx(1.0) and b["noise_ratio"] == 0.0


# --- rendered recordings -----------------------------------------------------------------------------------
def test_speckled_control_passes_and_tracks_within_the_predicted_accuracy(speckled) -> None:
    rec_dir, truth = speckled
    q = TrackQuality()
    rows = list(track_recording(open_recording(rec_dir), quality=q))
    tex = q.texture
    assert tex.noise.sigma_gray == pytest.approx(TRUE_NOISE, rel=0.05)  # the estimate against the rendered noise
    assert tex.warnings() == []
    err = _errors_px(rec_dir, truth, rows)
    summary = q.summary()["bodies"]
    for body in ("ball", "structure"):
        b = tex.bodies[body]
        assert b.n_usable == len(b.points)
        s = b.mesh_sigma_px[1] * TRUE_NOISE / tex.noise.sigma_gray  # the prediction at the true noise
        e = err[body]
        assert np.sqrt(np.mean(e ** 2)) <= 1.5 * s + INTERP_BIAS_PX, (body, s, e)
        assert np.abs(e).max() <= 5 * s + INTERP_BIAS_PX, (body, s, e)
        # the correlation's residual is the image noise alone (1 - ZNCC = s^2 / V): ratio ~1
        assert 0.8 <= summary[body]["noise_ratio"] <= 1.25, summary[body]


def _analyze(rec_dir, out, capsys):
    rc = vibro(["analyze", str(rec_dir), "--out", str(out), "--no-report", "--no-progress"])
    return rc, capsys.readouterr()


def test_shiny_ball_is_tracked_within_the_accuracy_its_highlight_gives_or_refused(shiny, tmp_path, capsys) -> None:
    rec_dir, truth = shiny
    out = tmp_path / "out"
    rc, cap = _analyze(rec_dir, out, capsys)
    if rc == 2:  # refused: it must say why, with the texture's numbers
        assert "texture check refused" in cap.err and "dic.ball_roi" in cap.err and "SSSIG" in cap.err
        return
    assert rc == 0, cap.err
    doc = json.loads((out / "results.json").read_text())
    quality = doc["dic_quality"]
    ball_tex = quality["texture"]["bodies"]["ball"]
    assert ball_tex["n_usable"] >= ball_tex["min_usable"]
    rows = read_dic_csv(out / "dic.csv")
    s_mm = truth["image"]["mm_per_px"]
    x = np.asarray(truth["frames"]["ball_mm"])
    e = (rows.ball_mm - (x - x[0])) / s_mm
    assert not rows.lost.any()
    # the highlight carries the texture: its predicted sigma, at the true noise, is the stated accuracy
    s = ball_tex["mesh_sigma_px"][1] * TRUE_NOISE / quality["texture"]["noise_gray"]
    assert s < 0.05  # usable texture, but several times the speckled ball's (~0.004 px)
    assert np.sqrt(np.mean(e ** 2)) <= 1.5 * s + INTERP_BIAS_PX, (s, e)
    assert np.abs(e).max() <= 5 * s + INTERP_BIAS_PX, (s, e)
    corr = quality["correlation"]["bodies"]["ball"]
    assert corr["frames_lost"] == 0 and corr["frames_tracked"] == FRAMES


def test_side_lit_shiny_ball_on_lossy_video_is_refused_naming_its_texture(shiny_side_lit_jpeg, tmp_path,
                                                                            capsys) -> None:
    rec_dir, _ = shiny_side_lit_jpeg
    out = tmp_path / "out"
    rc, cap = _analyze(rec_dir, out, capsys)
    assert rc == 2, cap.err
    line = cap.err.strip()
    assert "\n" not in line and "Traceback" not in line
    assert "texture check refused" in line and "dic.ball_roi" in line and "structure_roi" not in line
    assert "SSSIG" in line and "gray levels" in line and "sigma > 0.05 px" in line and "0 usable" in line
    assert not (out / "results.json").exists()
