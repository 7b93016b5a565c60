"""``vibro analyze``: end to end on a synthetic recording (track given), contract output, bad input."""

from __future__ import annotations

import json

import pytest

from vibro_app.cli import main
from vibro_fit.identify import track_rows
from vibro_fit.synthetic import accel_signals, paper_rig, sample_track, simulate
from vibro_io.accel import write_accel
from vibro_io.dictrack import write_dic_csv
from vibro_io.rig import write_rig

M_KG = 1.82e-4


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rec = tmp_path_factory.mktemp("rec")
    rig = paper_rig(accelerometers=True)
    write_rig(rig, rec / "rig.yaml")
    truth = simulate(amplitude_m=3e-3, duration_s=0.45, cor_jitter=0.03, seed=9,
                     force_up_n=-0.04 * M_KG * 9.81, force_down_n=0.02 * M_KG * 9.81)
    track = sample_track(truth, n_frames=400, noise_mm=0.0005)
    write_dic_csv(rec.parent / "dic.csv", track_rows(track))
    write_accel(rec / "accel.csv", accel_signals(truth, duration_s=0.4, offset_s=0.003), rig.accelerometers)
    return rec, rec.parent / "dic.csv", truth


def test_analyze_writes_contract_results_and_report(recording, tmp_path, capsys):
    rec, dic, truth = recording
    out = tmp_path / "out"
    rc = main(["analyze", str(rec), "--out", str(out), "--track", str(dic), "--no-progress"])
    assert rc == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["schema"] == "vibro.results/1"
    assert doc["recording"] == str(rec)
    for key in ("structure", "flights", "impacts", "cor_summary", "simulation", "discrepancy"):
        assert key in doc
    assert set(doc["simulation"]) >= {"cor_model", "hertz_model"}
    # replaying an exact COR-model motion with its own identified CORs and forces: the simulated ball
    # follows the measured one; D (Eq. 18) is limited by the identification errors (COR ~1e-4), far
    # below the paper's 2.5-3.5 % on real data. 1 % bound.
    d = doc["simulation"]["cor_model"]["deviation"]
    assert d is not None and d < 0.01
    # discrepancy (vibro_discrepancy): the baseline's constant COR cannot follow plates restituting
    # 0.6 vs 0.75 (scatter 0.03, 17 impacts: the difference is > 10 standard errors) -> found, D improves
    disc = doc["discrepancy"]
    assert disc["baseline_deviation"] > disc["final_deviation"] > 0
    asym = [f for f in disc["findings"] if f["effect"] == "asymmetric_restitution"]
    assert len(asym) == 1
    assert asym[0]["parameters"]["cor_top"] == pytest.approx(0.6, abs=0.04)      # ~3 standard errors
    assert asym[0]["parameters"]["cor_bottom"] == pytest.approx(0.75, abs=0.04)
    assert doc["accelerometers"]["clock_offset_s"] == pytest.approx(0.003, abs=1e-4)
    for name in ("report.html", "flights.csv", "impacts.csv", "displacements.png", "cor_per_impact.png",
                 "friction_per_flight.png", "cor_hist_qq.png", "accel_spectrum.png"):
        assert (out / name).is_file(), name
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html   # self-contained
    out_text = capsys.readouterr().out
    assert "regime" in out_text
    # the finding printed as vibro graph prints it: effect, main parameter +- its sigma, D before -> after (%)
    cor_top, sigma = asym[0]["parameters"]["cor_top"], asym[0]["parameters_std"]["cor_top"]
    line = next(x for x in out_text.splitlines() if x.startswith("finding: asymmetric_restitution"))
    assert f"cor_top = {cor_top:.4g} +- {sigma:.2g}" in line
    assert line.endswith(f"D {100 * asym[0]['deviation_before']:.3g} % -> {100 * asym[0]['deviation_after']:.3g} %")


def test_analyze_bad_track_is_one_line_error(recording, tmp_path, capsys):
    rec, dic, _ = recording
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,t_s\n0,0\n")
    rc = main(["analyze", str(rec), "--out", str(tmp_path / "o"), "--track", str(bad), "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert "bad.csv" in err and "line 1" in err and "Traceback" not in err


def test_analyze_missing_recording(tmp_path, capsys):
    rc = main(["analyze", str(tmp_path / "nope"), "--out", str(tmp_path / "o"), "--no-progress"])
    assert rc == 2
    assert "not a recording directory" in capsys.readouterr().err


def test_analyze_runs_dic_on_frames(tiny_recording, tmp_path, capsys):
    # the committed 5-frame recording goes through DIC, then identification refuses it by name
    rc = main(["analyze", str(tiny_recording), "--out", str(tmp_path / "o"), "--no-progress"])
    assert rc == 2
    assert "5 frames" in capsys.readouterr().err
    assert (tmp_path / "o" / "dic.csv").is_file()
