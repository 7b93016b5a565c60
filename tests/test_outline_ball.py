"""A plain ball (no speckle) tracked by its outline (issue #26): vibro_dic.outline, rig.yaml dic.ball_method outline.

Synthetic rig recordings of a backlit plain ball (``vibro synth --ball-surface plain``) go through ``vibro analyze``:
no frame lost, every measurable impact found, the centre's error against the truth within 1.5x the sigma the
outline check predicted before tracking, each impact's COR within 0.002 of the truth while the truth scatters by
0.015. The real Photron file ``ball_12bit`` (a backlit glass ball at 30 kfps, ../shared) is tracked in every frame
and its centre track leaves a parabola by no more than the predicted sigma.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from truth_impacts import measurable_impacts

from vibro_app.cli import main
from vibro_dic.outline import OutlineTracker, assess_outline, find_disc
from vibro_io.rig import Roi, parse_rig
from vibro_model.errors import RigError

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
BALL_12BIT = SHARED / "validation" / "lab_files" / "ball_12bit.cihx"
COR_SCATTER = 0.015
FRAMES = 400


# --- synthetic rig recordings through vibro analyze ----------------------------------------------------------
CASES = {  # noise (gray levels of 255), exposure blur, 12-bit frames
    "noise1-sharp-8bit": dict(noise_gray=1.0, blur=False, bits12=False, seed=2),
    "noise4-blur0.3ms-12bit": dict(noise_gray=4.0, blur=True, bits12=True, seed=5),
    "noise2-blur0.3ms-8bit": dict(noise_gray=2.0, blur=True, bits12=False, seed=7),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def analysed(request, tmp_path_factory):
    from vibro_sim.synth import SynthConfig, synthesize

    base = tmp_path_factory.mktemp(request.param)
    cfg = SynthConfig(frames=FRAMES, ball_surface="plain", cor_scatter=COR_SCATTER, exposure_s=0.3e-3,
                      **CASES[request.param])
    truth = synthesize(base / "rec", cfg, progress=False)
    assert main(["analyze", str(base / "rec"), "--out", str(base / "out"), "--no-progress", "--no-report"]) == 0
    doc = json.loads((base / "out" / "results.json").read_text())
    with open(base / "out" / "dic.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    rig = yaml.safe_load((base / "rec" / "rig.yaml").read_text())
    return truth, doc, rows, rig


def test_plain_ball_recording_is_tracked_by_its_outline_in_every_frame(analysed):
    truth, doc, rows, rig = analysed
    assert rig["dic"]["ball_method"] == "outline"
    assert len(rows) == FRAMES and not any(int(r["lost"]) for r in rows)
    # rotation is not measured on a plain disc
    assert all(math.isnan(float(r["ball_rot_rad"])) for r in rows)
    texture = doc["dic_quality"]["texture"]["bodies"]["ball"]
    assert texture["method"] == "outline" and texture["failure"] is None
    assert doc["dic_quality"]["correlation"]["bodies"]["ball"]["frames_lost"] == 0


def test_centre_error_is_within_the_predicted_sigma(analysed):
    truth, doc, rows, _ = analysed
    ball = np.array([float(r["ball_mm"]) for r in rows])
    true = np.asarray(truth["frames"]["ball_mm"])
    err_px = (ball - (true - true[0])) / truth["image"]["mm_per_px"]
    # a frame whose exposure holds an impact shows the ball before and after it: no single centre is true there
    t = np.asarray(truth["frames"]["t_s"])
    t_imp = np.array([i["t"] for i in truth["impacts"]])
    half_exposure = 0.5 * truth["config"]["exposure_s"] if truth["config"]["blur"] else 0.0
    clean = np.min(np.abs(t[:, None] - t_imp[None, :]), axis=1) > half_exposure
    assert clean.sum() >= 0.95 * len(t)
    predicted = doc["dic_quality"]["texture"]["bodies"]["ball"]["mesh_sigma_px"][1]  # motion axis (rows)
    # a displacement is this frame's centre minus frame 0's: e_k = n_k - n_0, both of one frame's sigma, the
    # predicted displacement sigma / sqrt(2). n_0 is one draw common to every frame: the RMS over frames is
    # sqrt(s1^2 + n_0^2) and exceeds 1.5x the prediction whenever |n_0| > 1.87 s1 (6 % of recordings, however
    # right the prediction). So the two parts are checked apart: the scatter about the mean against one frame's
    # sigma (0.5x: not vacuous, 1.5x: the issue's bound), the common offset against frame 0's sigma (4 sigma)
    one_frame = predicted / math.sqrt(2.0)
    e = err_px[clean]
    assert 0.5 * one_frame <= float(np.std(e)) <= 1.5 * one_frame, (float(np.std(e)), one_frame)
    assert abs(float(np.mean(e))) <= 4.0 * one_frame, (float(np.mean(e)), one_frame)


def test_every_impact_is_found_and_its_cor_within_0_002(analysed):
    truth, doc, _, _ = analysed
    measurable = measurable_impacts(truth)
    assert len(measurable) >= 15
    t_found = np.array([i["t"] for i in doc["impacts"]])
    errors = []
    for imp in measurable:
        k = int(np.argmin(np.abs(t_found - imp["t"])))
        assert abs(t_found[k] - imp["t"]) < 0.5e-3, f"impact at {imp['t']:.4f} s not found"
        found = doc["impacts"][k]
        assert found["plate"] == imp["plate"]
        errors.append(found["cor"] - imp["cor"])
    assert np.max(np.abs(errors)) <= 0.002
    # the truth's per-impact scatter (0.015) is resolved, not averaged away: the errors are far below it
    cors = np.array([i["cor"] for i in measurable])
    assert np.std(cors) > 0.5 * COR_SCATTER
    assert np.std(errors) < 0.1 * np.std(cors)


# --- the outline's pieces on drawn images ---------------------------------------------------------------------
def _disc_image(cx: float, cy: float, radius: float, *, inside: float = 30.0, outside: float = 200.0,
                shape=(200, 200), edge_sigma: float = 0.6) -> np.ndarray:
    from scipy.special import ndtr

    yy, xx = np.mgrid[:shape[0], :shape[1]]
    r = np.hypot(xx - cx, yy - cy)
    return outside + (inside - outside) * ndtr((radius - r) / edge_sigma)


def test_predicted_sigma_matches_the_scatter_over_noise_realisations():
    clean = _disc_image(100.3, 97.8, 35.0)
    roi = Roi(55, 52, 92, 92)
    noise = 3.0
    rng = np.random.default_rng(1)
    check = assess_outline("ball", clean + rng.normal(0, noise, clean.shape), roi, noise)
    tracker = OutlineTracker("ball", clean + rng.normal(0, noise, clean.shape), roi)
    centres = np.array([tracker.track((clean + rng.normal(0, noise, clean.shape)).astype(np.float32), k).u_px
                        for k in range(1, 81)])
    # displacement = this frame's centre - the reference's: the reference's error is common to all 80 frames,
    # so the scatter about their mean is one frame's sigma, the predicted displacement sigma / sqrt(2)
    scatter = centres.std(axis=0, ddof=1)
    one_frame = np.asarray(check.mesh_sigma_px) / math.sqrt(2)
    # 80 samples: the std's relative standard error is 1 / sqrt(158) = 8 %; +-30 % is ~3.7 of them
    assert np.all(np.abs(scatter / one_frame - 1.0) < 0.3), (scatter, one_frame)


def test_an_occluding_plate_leaves_the_centre_exact_and_is_reported():
    truth = np.array([100.0, 100.25])
    img = _disc_image(*truth, 35.0)
    img[:70, :] = 110.0  # a plate over the top of the ball (rows < 70: the top 5 px of the disc)
    ref = _disc_image(100.0, 100.0, 35.0)
    tracker = OutlineTracker("ball", ref, Roi(55, 55, 91, 91))
    res = tracker.track(img.astype(np.float32), 1)
    assert not res.lost
    assert res.valid < tracker.n_sectors  # the occluded sectors were left out
    assert np.allclose(res.u_px, truth - tracker.centre0, atol=0.01)


def test_a_weak_outline_is_refused_with_its_numbers():
    img = _disc_image(100.0, 100.0, 35.0, inside=120.0, outside=135.0)
    check = assess_outline("ball", img, Roi(55, 55, 91, 91), noise_gray=4.0)
    assert check.refused
    msg = check.problem()
    assert "contrast" in msg and "noise of 4" in msg and "predicted displacement sigma" in msg


def test_a_bright_ball_on_a_dark_background_is_found():
    img = _disc_image(90.0, 110.0, 30.0, inside=220.0, outside=25.0)
    disc = find_disc(img, Roi(50, 70, 80, 80))
    assert disc is not None and disc.polarity == -1
    assert abs(disc.cx - 90.0) < 0.5 and abs(disc.cy - 110.0) < 0.5 and abs(disc.radius_px - 30.0) < 0.5


def test_an_outline_leaving_the_image_is_lost_with_the_reason():
    ref = _disc_image(100.0, 100.0, 35.0)
    tracker = OutlineTracker("ball", ref, Roi(55, 55, 91, 91))
    res = tracker.track(_disc_image(100.0, 185.0, 35.0).astype(np.float32), 1)
    assert res.lost and "image" in res.reason


def test_rig_ball_method_is_validated():
    base = {"camera": {"fps": 1000.0, "t0_s": 0.0, "mm_per_px": 0.06},
            "ball": {"mass_kg": 1e-4, "diameter_mm": 4.0, "youngs_modulus_pa": 2e11, "poisson_ratio": 0.3},
            "structure": {"gap_mm": 10.0, "mass_kg": 0.5, "youngs_modulus_pa": 7e10, "poisson_ratio": 0.33},
            "excitation": {"frequency_hz": 22.0},
            "dic": {"subset_px": 31, "mesh_step_px": 10, "ball_roi": [10, 10, 90, 90],
                    "structure_roi": [0, 200, 100, 40]}}
    assert parse_rig(base).dic.ball_method == "mesh"
    assert "ball_method" not in parse_rig(base).to_dict()["dic"]  # the default is not written
    base["dic"]["ball_method"] = "outline"
    assert parse_rig(base).to_dict()["dic"]["ball_method"] == "outline"
    base["dic"]["ball_method"] = "edge"
    with pytest.raises(RigError, match="ball_method.*mesh, outline"):
        parse_rig(base)


# --- the real Photron file --------------------------------------------------------------------------------
BALL_12BIT_RIG = {
    "camera": {"mm_per_px": 0.05},
    "ball": {"mass_kg": 1e-4, "diameter_mm": 6.35, "youngs_modulus_pa": 6e10, "poisson_ratio": 0.2},
    "structure": {"gap_mm": 100.0, "mass_kg": 0.5, "youngs_modulus_pa": 7e10, "poisson_ratio": 0.33},
    "excitation": {"frequency_hz": 22.0},
    # the ball box drawn around the whole ball in frame 0 (centre ~(175, 109), radius ~64 px) with a margin;
    # the structure: the textured plate at the bottom
    "dic": {"subset_px": 31, "mesh_step_px": 10, "ball_roi": [101, 35, 149, 149], "structure_roi": [8, 336, 368, 40],
            "ball_method": "outline"},
}


@pytest.mark.skipif(not BALL_12BIT.exists(), reason="../shared/validation/lab_files is not there")
def test_ball_12bit_is_tracked_in_every_frame_within_its_predicted_sigma(tmp_path):
    rec = tmp_path / "ball"
    rec.mkdir()
    for suffix in (".cihx", ".mraw"):
        shutil.copy(BALL_12BIT.with_suffix(suffix), rec / f"ball_12bit{suffix}")
    (rec / "rig.yaml").write_text(yaml.safe_dump(BALL_12BIT_RIG, sort_keys=False))
    assert main(["track", str(rec), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    with open(tmp_path / "out" / "dic.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 15 and not any(int(r["lost"]) for r in rows)  # 15/15 frames tracked
    # the ball falls ~2.6 px a frame; over 0.5 ms gravity and drag are a parabola to far below a px
    down_px = -np.array([float(r["ball_mm"]) for r in rows]) / BALL_12BIT_RIG["camera"]["mm_per_px"]
    k = np.arange(15)
    residual = down_px - np.polyval(np.polyfit(k, down_px, 2), k)
    rms = math.sqrt(float(residual @ residual) / (15 - 3))
    from vibro_dic.texture import estimate_noise
    from vibro_io.frames import FrameSequence
    from vibro_io.rig import CameraConfig

    seq = FrameSequence(rec / "ball_12bit.cihx", CameraConfig(fps=30000.0, t0_s=0.0, mm_per_px=1.0))
    frames = [f.image for f in seq.iter_slots(0, 2)]
    noise = estimate_noise(frames[0], frames[1], effective_bits=seq.effective_bits, codec=seq.codec)
    check = assess_outline("ball", frames[0].astype(np.float32), Roi(*BALL_12BIT_RIG["dic"]["ball_roi"]),
                           noise.sigma_gray)
    assert not check.refused
    assert rms <= check.mesh_sigma_px[1], (rms, check.mesh_sigma_px)
