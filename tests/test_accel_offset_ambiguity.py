"""Camera-to-DAQ clock offset: refused when the records cannot tell it (ambiguous or too little overlap),
stated with its overlap when they can (issue #11, item 1)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from vibro_app.cli import main
from vibro_fit.accel_impacts import estimate_clock_offset

PERIOD_S = 1.0 / 22.0


def _keep_accel_rows(src, dst, t_max_s: float) -> None:
    """accel.csv of ``src`` cut after ``t_max_s`` (DAQ clock), written to ``dst`` (a real file cut short)."""
    lines = (src / "accel.csv").read_text().splitlines()
    keep = [lines[0]] + [ln for ln in lines[1:] if float(ln.split(",")[0]) <= t_max_s]
    (dst / "accel.csv").write_text("\n".join(keep) + "\n")


@pytest.fixture(scope="module")
def half(tmp_path_factory):
    """A regular two-impacts-per-cycle recording (constant COR: impacts repeat every shaker period) whose
    accel.csv covers only the first half of the video; analysed once with DIC, then variants on its track."""
    from vibro_sim.synth import SynthConfig, synthesize

    base = tmp_path_factory.mktemp("offset")
    rec = base / "rec"
    truth = synthesize(rec, SynthConfig(frames=600, seed=5), progress=False)
    full = base / "full_accel"
    full.mkdir()
    shutil.copy(rec / "rig.yaml", full / "rig.yaml")
    shutil.copy(rec / "accel.csv", full / "accel.csv")
    _keep_accel_rows(full, rec, 0.3)
    rc = main(["analyze", str(rec), "--out", str(base / "out"), "--no-progress", "--no-report"])
    assert rc == 0
    return base, rec, full, truth


def test_half_covered_regular_recording_refuses_the_offset(half, capsys):
    # the old code reported -0.273 s (six shaker periods off, truth 0) as known; every whole-period shift
    # of the half-length accelerometer record inside the video matches the same number of impacts
    base, rec, _, truth = half
    doc = json.loads((base / "out" / "results.json").read_text())
    acc = doc["accelerometers"]
    assert truth["clock_offset_s"] == 0.0
    assert acc["clock_offset_s"] is None
    off = acc["clock_offset"]
    assert off["determined"] is False and "ambiguous" in off["reason"]
    # the overlap is stated: impacts matched at the best candidate and a rival a whole number of periods away
    assert off["n_matched"] >= 10 and off["n_accel_impacts"] >= off["n_matched"]
    rival = off["candidates"][0]
    shift_periods = (rival["offset_s"] - off["best_candidate_s"]) / PERIOD_S
    assert abs(shift_periods - round(shift_periods)) < 0.02 and round(shift_periods) != 0
    assert rival["n_matched"] >= off["n_matched"] - 1
    msg = next(w for w in doc["warnings"] if "clock offset unknown" in w)
    assert "ambiguous" in msg and "shaker periods" in msg and "record lasts" in msg
    # nothing built on a guessed offset: the coverage says the offset is unknown
    assert acc["coverage"]["clock_offset_known"] is False


def test_too_little_overlap_refuses_the_offset(half, tmp_path):
    # 60 ms of accelerometer data: 2-3 impacts in common, fewer than the 4 the offset needs
    base, rec, full, _ = half
    short = tmp_path / "short"
    short.mkdir()
    shutil.copy(rec / "rig.yaml", short / "rig.yaml")
    _keep_accel_rows(full, short, 0.06)
    out = tmp_path / "out"
    assert main(["analyze", str(short), "--track", str(base / "out" / "dic.csv"), "--out", str(out),
                 "--no-progress", "--no-report"]) == 0
    doc = json.loads((out / "results.json").read_text())
    off = doc["accelerometers"]["clock_offset"]
    assert doc["accelerometers"]["clock_offset_s"] is None
    assert off["determined"] is False and "too little overlap" in off["reason"]
    assert off["n_matched"] < 4
    assert any("too little overlap" in w for w in doc["warnings"])


def test_full_overlap_offset_is_determined_and_its_overlap_stated(half, tmp_path, capsys):
    # control: the same recording with its whole accel.csv: the offset (truth 0) is found, to the onset
    # latency of the accelerometer detector (0.1 ms), with the matched span stated
    base, _, full, truth = half
    out = tmp_path / "out"
    assert main(["analyze", str(full), "--track", str(base / "out" / "dic.csv"), "--out", str(out),
                 "--no-progress", "--no-report"]) == 0
    doc = json.loads((out / "results.json").read_text())
    off = doc["accelerometers"]["clock_offset"]
    assert off["determined"] is True
    assert doc["accelerometers"]["clock_offset_s"] == pytest.approx(truth["clock_offset_s"], abs=1e-4)
    lo, hi = off["matched_span_s"]
    assert hi - lo > 0.5   # 0.6 s of video: the matches span it, edges aside
    assert off["n_matched"] >= len(doc["impacts"]) - 1
    assert "matched over" in capsys.readouterr().out


def test_offset_from_jittered_impacts_is_unique_even_on_half_overlap():
    # uneven impact intervals (COR scatter) make the offset unique: a half-length record still finds it
    rng = np.random.default_rng(1)
    cam = np.cumsum(rng.uniform(0.018, 0.030, 40))
    daq = cam[cam < cam[20]] + 0.0123
    off = estimate_clock_offset(daq, cam, period_s=PERIOD_S)
    assert off.determined and off.offset_s == pytest.approx(0.0123, abs=1e-6)
    assert off.n_matched == daq.size
    # the same times made periodic (every 1/22 s): undetermined, the rival a whole period away
    cam_p = np.arange(40) * PERIOD_S + 0.01
    daq_p = cam_p[:20] + 0.0123
    off_p = estimate_clock_offset(daq_p, cam_p, period_s=PERIOD_S)
    assert not off_p.determined and off_p.known_offset_s is None and "ambiguous" in off_p.reason
