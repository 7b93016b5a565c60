"""Impacts inside runs of dropped frames (issue #27 item 2): a `vibro synth` recording whose frame files
are deleted around known impacts (the truth file says where), analysed by `vibro analyze`. One impact
inside a 4-frame gap is found (time within its sigma, COR right), marked ``in_gap``; a gap that hides two
impacts reports what it may hide and invents none; a gap inside a flight invents nothing."""

from __future__ import annotations

import json
import math
import os
import shutil

import numpy as np
import pytest

from vibro_app.cli import main

FRAMES = 400
FPS = 1000.0
SIGMAS = 3.0        # a measured time/COR must agree with the truth within this many of its own sigmas


def _analyze(rec, out):
    rc = main(["analyze", str(rec), "--out", str(out), "--no-progress", "--no-report"])
    assert rc == 0
    return json.loads((out / "results.json").read_text())


def _without_frames(src, dst, frames, accel=True):
    """A copy of recording ``src`` (files hard-linked) without the frame files ``frames``."""
    dst.mkdir()
    shutil.copytree(src / "frames", dst / "frames", copy_function=os.link)
    shutil.copy(src / "rig.yaml", dst / "rig.yaml")
    if accel:
        shutil.copy(src / "accel.csv", dst / "accel.csv")
    else:   # a video-only recording: the rig's accelerometers block (the file's last) goes too
        text = (src / "rig.yaml").read_text()
        assert text.count("accelerometers:") == 1
        (dst / "rig.yaml").write_text(text[:text.index("accelerometers:")])
    names = sorted(p.name for p in (src / "frames").iterdir())
    for k in frames:
        (dst / "frames" / names[k]).unlink()


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    from vibro_sim.synth import SynthConfig, synthesize

    base = tmp_path_factory.mktemp("gaps")
    truth = synthesize(base / "rec", SynthConfig(frames=FRAMES, seed=3, cor_scatter=0.015), progress=False)
    return base, truth


def _truth_impacts(truth):
    return [(float(i["t"]), float(i["cor"]), i["plate"]) for i in truth["impacts"]]


def _middle_impact(truth, k=None):
    """A true impact far from both ends of the recording (its index in the truth list)."""
    imps = _truth_impacts(truth)
    inside = [j for j, (t, _, _) in enumerate(imps) if 0.12 < t < 0.3]
    return inside[0] if k is None else inside[k]


def _assert_all_real(doc, truth):
    """Every reported impact is a true one: within 0.5 ms (a twentieth of a frame pair) and its COR within
    0.02 (the COR scatter's 1.3 sigma would pass a wrong pairing of parabolas only by luck)."""
    tt = np.array([t for t, _, _ in _truth_impacts(truth)])
    for est in doc["impacts"]:
        j = int(np.argmin(abs(tt - est["t"])))
        assert abs(tt[j] - est["t"]) < 5e-4, f"impact at {est['t']:.4f} s matches no true impact"
        assert abs(est["cor"] - truth["impacts"][j]["cor"]) < 0.02


@pytest.mark.parametrize("accel", [True, False])
def test_impact_inside_four_dropped_frames_is_found_with_its_sigma(rec, tmp_path, accel):
    base, truth = rec
    j = _middle_impact(truth)
    t_hit, cor_hit, plate = _truth_impacts(truth)[j]
    f = int(math.floor(t_hit * FPS))
    _without_frames(base / "rec", tmp_path / "rec", range(f - 1, f + 3), accel=accel)   # 4 frames, impact inside
    doc = _analyze(tmp_path / "rec", tmp_path / "out")
    _assert_all_real(doc, truth)
    gap = [i for i in doc["impacts"] if i.get("in_gap")]
    assert len(gap) == 1
    (est,) = gap
    assert est["plate"] == plate and est["gap_lost_frames"] == 4
    assert (f - 1) / FPS < est["t"] < (f + 3) / FPS
    assert abs(est["t"] - t_hit) <= SIGMAS * est["t_std"]
    assert abs(est["cor"] - cor_hit) <= SIGMAS * est["cor_std"]
    assert abs(est["cor"] - cor_hit) <= 0.002
    (verdict,) = doc["identification"]["gaps"]
    assert verdict["determined"] and verdict["impact_index"] == est["index"]
    # the filmed impacts are all still there: the gap costs none
    full = [t for t, _, _ in _truth_impacts(truth) if 0.01 < t < (FRAMES - 2) / FPS]
    assert len(doc["impacts"]) >= len(full) - 1


@pytest.mark.parametrize("accel", [True, False])
def test_gap_hiding_two_impacts_is_reported_not_invented(rec, tmp_path, accel):
    # with the accelerometers their two impacts in the gap decide; without, the flights alone: the gap is
    # longer than the flights beside it, so no extrapolation is trusted across it
    base, truth = rec
    j = _middle_impact(truth)
    imps = _truth_impacts(truth)
    t1, t2 = imps[j][0], imps[j + 1][0]
    lo, hi = int(math.floor(t1 * FPS)) - 3, int(math.floor(t2 * FPS)) + 4
    _without_frames(base / "rec", tmp_path / "rec", range(lo, hi + 1), accel=accel)
    doc = _analyze(tmp_path / "rec", tmp_path / "out")
    _assert_all_real(doc, truth)
    assert not [i for i in doc["impacts"] if lo / FPS <= i["t"] <= hi / FPS]
    (verdict,) = doc["identification"]["gaps"]
    assert not verdict["determined"]
    assert verdict["may_hide_min"] <= 2 <= verdict["may_hide_max"]
    assert any("may hide" in w and "have no DIC result" in w for w in doc["warnings"])


def test_gap_inside_a_flight_invents_no_impact(rec, tmp_path):
    base, truth = rec
    j = _middle_impact(truth)
    imps = _truth_impacts(truth)
    mid = int(round(0.5 * (imps[j][0] + imps[j + 1][0]) * FPS))
    _without_frames(base / "rec", tmp_path / "rec", range(mid - 2, mid + 3))
    doc = _analyze(tmp_path / "rec", tmp_path / "out")
    _assert_all_real(doc, truth)
    assert not [i for i in doc["impacts"] if i.get("in_gap")]
    assert not [i for i in doc["impacts"] if imps[j][0] + 1e-3 < i["t"] < imps[j + 1][0] - 1e-3]
