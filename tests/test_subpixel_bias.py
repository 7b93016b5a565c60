"""Issue 39: DIC's sub-pixel bias (the S-curve) is measured on the recording and taken out (vibro_fit.subpixel_bias).

Ground truth: (1) tracks built here from known motion, white noise of the rendered recordings' size and an
S-curve b(d) of known coefficients; (2) a rendered recording (``vibro synth``: drag and drive harmonics at once,
the case whose CORs were 35 % within 2 sigma) with its truth file. Properties: the S-curve is recovered within its
standard errors and taken out; white noise alone, or a body that sweeps too few pixels, changes nothing; on the
rendered recording the corrected track is closer to the true motion, the published CORs are closer to the true
ones, and their 2-sigma coverage reaches the nominal share, where without the correction it does not.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import vibro_fit.subpixel_bias as sb
from vibro_io.dic_bias import SubpixelBias, bias_columns, track_as_identified
from vibro_io.dictrack import DicTrack, read_dic_csv
from vibro_model.errors import RecordingError

MM_PER_PX = 0.06
NOISE_MM = 1.0e-4          # the white part of the rendered recordings' DIC error after the S-curve (~0.1-0.2 um)
S_CURVE = np.array([2.2e-4, 1.0e-5, 1.5e-5, -5e-6])   # a_1, b_1, a_2, b_2 (mm): 0.0037 px, as measured there
F_HZ = 22.0


def _structure(t: np.ndarray, amplitude_mm: float) -> np.ndarray:
    w = 2 * np.pi * F_HZ
    return amplitude_mm * (np.sin(w * t + 0.3) + 0.02 * np.sin(3 * w * t - 0.8) + 0.05 * np.sin(2 * w * t + 0.5))


def _ball_flights(t: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """A ball bouncing in 25 ms flights (cubic: gravity and a drag-like term), and each flight's frames."""
    y = np.empty_like(t)
    frames = []
    period = 0.025
    k = np.floor(t / period).astype(int)
    for j in np.unique(k):
        sel = np.nonzero(k == j)[0]
        tau = t[sel] - j * period
        y[sel] = 3.0 + 720.0 * tau - 4905.0 * tau ** 2 + 900.0 * tau ** 3 + 0.05 * j
        frames.append(sel[1:-1])        # the frames around the impacts are not in a flight
    return y, frames


def _track(s_mm: np.ndarray, b_mm: np.ndarray, t: np.ndarray) -> DicTrack:
    n = t.size
    return DicTrack(frame=np.arange(n), t_s=t, ball_mm=b_mm, structure_mm=s_mm, ball_valid=np.full(n, 4),
                    structure_valid=np.full(n, 24), ball_zncc=np.ones(n), structure_zncc=np.ones(n),
                    lost=np.zeros(n, bool))


def _with_bias(y_mm: np.ndarray, rng: np.random.Generator, coefs=S_CURVE) -> np.ndarray:
    return y_mm + bias_columns(y_mm, MM_PER_PX, 2) @ coefs + rng.normal(0.0, NOISE_MM, y_mm.size)


def test_a_known_s_curve_is_recovered_within_its_sigmas_and_taken_out() -> None:
    rng = np.random.default_rng(3)
    t = np.arange(3000) / 1000.0
    s_true, (b_true, frames) = _structure(t, 1.41), _ball_flights(t)
    track = _track(_with_bias(s_true, rng), _with_bias(b_true, rng), t)
    bias = sb.subpixel_bias(track, frames, F_HZ, MM_PER_PX)
    for body in (bias.structure, bias.ball):
        assert body.applied, body.reason
        coef, std = np.array(body.coefficients_mm), np.array(body.coefficient_std_mm)
        assert np.all(np.abs(coef - S_CURVE) < 4 * std), (body.body, coef, std)
        # the standard errors are the noise's: sigma / sqrt(n / 2) per coefficient, within 30 %
        assert np.all(std < 1.3 * NOISE_MM / math.sqrt(body.frames / 2)), (body.body, std)
    fixed = bias.corrected(track)
    for got, true in ((fixed.structure_mm, s_true), (fixed.ball_mm, b_true)):
        err = got - true
        assert np.std(err) < 1.1 * NOISE_MM            # only the white noise is left
    # the results section carries it: the same track from the section as from the identification
    again = track_as_identified(track, json.loads(json.dumps(bias.to_dict())))
    assert np.array_equal(again.ball_mm, fixed.ball_mm) and np.array_equal(again.structure_mm, fixed.structure_mm)


def test_white_noise_alone_changes_nothing() -> None:
    t = np.arange(3000) / 1000.0
    s_true, (b_true, frames) = _structure(t, 1.41), _ball_flights(t)
    applied = 0
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        track = _track(_with_bias(s_true, rng, 0 * S_CURVE), _with_bias(b_true, rng, 0 * S_CURVE), t)
        bias = sb.subpixel_bias(track, frames, F_HZ, MM_PER_PX)
        applied += bias.structure.applied + bias.ball.applied
        assert bias.corrected(track) is track or not bias.applied
    assert applied == 0                        # a 5-sigma test on 40 bodies: no false alarm expected


def test_a_body_that_sweeps_a_pixel_is_left_alone() -> None:
    rng = np.random.default_rng(5)
    t = np.arange(3000) / 1000.0
    s_true = _structure(t, 0.02)               # +-0.33 px: b(d) is a smooth function of the motion itself
    (b_true, frames) = _ball_flights(t)
    track = _track(_with_bias(s_true, rng), _with_bias(b_true, rng), t)
    bias = sb.subpixel_bias(track, frames, F_HZ, MM_PER_PX)
    assert not bias.structure.applied and "sweeps" in bias.structure.reason
    assert bias.ball.applied                   # the ball still sweeps tens of pixels


def test_a_damaged_section_is_refused_naming_it() -> None:
    t = np.arange(100) / 1000.0
    track = _track(np.zeros_like(t), np.zeros_like(t), t)
    good = SubpixelBias(mm_per_px=MM_PER_PX).to_dict()
    assert track_as_identified(track, None) is track
    assert track_as_identified(track, good) is track                    # nothing applied: the same track
    for bad, where in (({**good, "mm_per_px": -1}, "mm_per_px"),
                       ({**good, "ball": {**good["ball"], "applied": "yes"}}, "ball.applied"),
                       ({**good, "ball": {**good["ball"], "applied": True, "coefficients_mm": [1e-4]}},
                        "ball.coefficients_mm"),
                       ([], "dic_bias")):
        with pytest.raises(RecordingError, match=where):
            track_as_identified(track, bad)


# ---------------------------------------------------------------- a rendered recording
TWO_EFFECTS = ["--effect", "quadratic_drag", "--param", "coefficient_ns2_per_m2=5e-4", "--effect",
               "structure_harmonics"]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> dict:
    """Drag and drive harmonics at once (seed 3: its CORs were 38 % within 2 sigma before the correction),
    rendered and tracked by ``vibro analyze``.

    The premise is the realisation's: over seeds 1-9 the CORs before the correction were within 2 sigma at
    0.35-1.00 (the S-curve moves the drag coefficient's estimate, which every COR shares), after it at 0.80-1.00
    (that coefficient's error, about half of each COR's variance, moves all of one recording's CORs together).
    Seed 2 showed the premise until the synthetic read noise was drawn differently (session 23); seed 3 shows it
    with either draw."""
    base = tmp_path_factory.mktemp("subpixel")
    rec, out = base / "rec", base / "out"
    cli = [sys.executable, "-m", "vibro_app.cli"]
    made = subprocess.run([*cli, "synth", "--out", str(rec), "--seed", "3", "--frames", "1500", "--no-accel",
                           "--no-progress", *TWO_EFFECTS], capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr
    ran = subprocess.run([*cli, "analyze", str(rec), "--out", str(out), "--no-report", "--no-progress"],
                         capture_output=True, text=True, timeout=300)
    assert ran.returncode == 0, ran.stderr
    return {"rec": rec, "out": out, "truth": json.loads(Path(f"{rec}.truth.json").read_text()),
            "results": json.loads((out / "results.json").read_text())}


def _published(rendered: dict, monkeypatch, correct: bool) -> tuple[list, SubpixelBias | None]:
    """The published impacts of the recording's dic.csv (identification, discrepancy, re-identification in this
    process, as analyze runs them), with the sub-pixel correction or (``correct`` False) without it."""
    from vibro_discrepancy.engine import run_discrepancy
    from vibro_discrepancy.reidentify import reidentification
    from vibro_fit.identify import identify
    from vibro_fit.results import results_document
    from vibro_io.rig import load_rig
    from vibro_model.assemble import apply_reidentification
    from vibro_model.results import ResultsDocument

    if not correct:
        monkeypatch.setattr(sb, "MIN_Z", math.inf)
    rig = load_rig(rendered["rec"] / "rig.yaml")
    track = read_dic_csv(rendered["out"] / "dic.csv")
    ident = identify(track, rig)
    doc = ResultsDocument.from_dict(results_document(ident, "test"))
    run = run_discrepancy(doc, ident.corrected_track(track), rig)
    final = apply_reidentification(doc, reidentification(run.result.findings, run))
    return final.impacts, ident.dic_bias


def _scores(impacts, truth) -> tuple[float, float]:
    """(2-sigma coverage, mean |COR error|) against the true impact nearest in time."""
    tt = np.array([i["t"] for i in truth["impacts"]])
    te = np.array([i["cor"] for i in truth["impacts"]])
    err, sd = [], []
    for imp in impacts:
        if imp.cor is None or imp.cor_std is None:
            continue
        err.append(imp.cor - te[int(np.argmin(np.abs(tt - imp.t_s)))])
        sd.append(imp.cor_std)
    err, sd = np.abs(np.array(err)), np.array(sd)
    assert err.size >= 50
    return float(np.mean(err < 2 * sd)), float(np.mean(err))


def test_on_a_rendered_recording_the_track_and_the_cors_come_closer_to_the_truth(rendered, monkeypatch) -> None:
    r, truth = rendered["results"], rendered["truth"]
    section = r["dic_bias"]
    assert section["structure"]["applied"] and section["ball"]["applied"], section
    for body in ("structure", "ball"):       # a bias of a few thousandths of a pixel, well told from noise
        amp, std = section[body]["amplitude_px"], section[body]["amplitude_std_px"]
        assert 5e-4 < amp < 0.05 and amp > 10 * std
    from vibro_app.report_methods import subpixel_bias_row  # the report's Methods say it, per body

    key, _, text = subpixel_bias_row(r)
    assert key == "dic.subpixel_bias" and text.count("taken out;") == 2
    # against the true motion: the corrected track's error is smaller (the S-curve was most of it)
    raw = read_dic_csv(rendered["out"] / "dic.csv")
    fixed = track_as_identified(raw, section)
    for name in ("structure_mm", "ball_mm"):
        true = np.array(truth["frames"][name])
        e_raw = getattr(raw, name) - (true - true[0])
        e_fix = getattr(fixed, name) - (true - true[0])
        assert np.std(e_fix) < 0.85 * np.std(e_raw), name
    # what analyze published: the CORs within 2 of their sigmas at the nominal share
    after, bias = _published(rendered, monkeypatch, correct=True)
    assert bias is not None and bias.applied
    cover_after, mae_after = _scores(after, truth)
    assert cover_after >= 0.9
    # analyze's own CORs (this read dic.csv, written to 9 digits: ~1e-10 in a COR)
    assert [i.cor for i in after] == pytest.approx([i["cor"] for i in r["impacts"]], abs=1e-8)
    # the same dic.csv without the correction: the premise (COR errors of one sign beyond the white-noise sigmas)
    before, _ = _published(rendered, monkeypatch, correct=False)
    cover_before, mae_before = _scores(before, truth)
    assert cover_before < 0.9 and mae_after < 0.75 * mae_before, (cover_before, mae_before, mae_after)
