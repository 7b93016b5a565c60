"""The rig's orientation (issue 40, part 1): rig.yaml ``setup.axis_tilt_deg``, the paper's Fig. 11 study.

Synthetic recordings (`vibro synth --axis-tilt-deg`) at 0, 45 and 90 degrees analysed by `vibro campaign`, one
declared at 45 whose axis is truly at 50 analysed by `vibro analyze`, each scored against its truth file. The
tolerances come from the measurement's own sigmas (Eq. 16's cor_std, Eq. 17's friction_std_n), the physical
floor of a force in flight (1e-3 of the ball's weight, docs/method.md) and what the vertical rig achieves.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from vibro_app.cli import main
from vibro_app.findings_text import findings_lines
from vibro_io.rig import parse_rig
from vibro_model.constants import G_MPS2
from vibro_model.errors import RigError

FRAMES = 700
TILTS = (0, 45, 90)
SCATTER = 0.015            # per-impact COR scatter (the paper's Fig. 14-16): the COR table is not a constant
GUIDE_RODS_N = 2.0e-4      # the horizontal rig's Coulomb friction (0.11 m g), a force the analysis must find
FLOOR_OF_WEIGHT = 1e-3     # physical floor of a force in flight (vibro_fit.plausibility.FRICTION_FLOOR_OF_WEIGHT)
K_SIGMA = 4.0
WEIGHT_N = 1.82e-4 * G_MPS2   # the synthetic rig's ball (vibro_sim.params.BALL_MASS_KG): its weight m g


def _synth(out: Path, tilt: float, *extra: str) -> dict:
    argv = ["synth", "--out", str(out), "--axis-tilt-deg", str(tilt), "--frames", str(FRAMES), "--seed", "3",
            "--cor-scatter", str(SCATTER), "--no-accel", "--no-progress", *extra]
    assert main(argv) == 0
    return json.loads(Path(f"{out}.truth.json").read_text())


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """The Fig. 11 study as a user runs it: three recordings, one `vibro campaign`."""
    base = tmp_path_factory.mktemp("orientation")
    src, out = base / "recordings", base / "campaign"
    src.mkdir()
    truths = {}
    for tilt in TILTS:
        extra = ("--effect", "coulomb_friction", "--param", f"force_n={GUIDE_RODS_N}") if tilt == 90 else ()
        truths[tilt] = _synth(src / f"axis{tilt}", tilt, *extra)
    assert main(["campaign", str(src), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    docs = {t: json.loads((out / f"axis{t}" / "results.json").read_text()) for t in TILTS}
    return {"src": src, "out": out, "truths": truths, "docs": docs}


@pytest.fixture(scope="module")
def declared_45_true_50(tmp_path_factory):
    base = tmp_path_factory.mktemp("tilt50")
    truth = _synth(base / "rec", 45, "--effect", "gravity_tilt", "--param", "tilt_deg=50")
    assert main(["analyze", str(base / "rec"), "--out", str(base / "out"), "--no-progress", "--no-report"]) == 0
    return truth, json.loads((base / "out" / "results.json").read_text())


def _matched_cor_errors(doc: dict, truth: dict) -> tuple[np.ndarray, np.ndarray]:
    """(COR error against the truth, the error in the analysis' own sigmas) of every impact matched to a true
    impact on the same plate within 2 frames."""
    t_true = np.array([i["t"] for i in truth["impacts"]])
    err, z = [], []
    for imp in doc["impacts"]:
        k = int(np.argmin(np.abs(t_true - imp["t"])))
        if abs(t_true[k] - imp["t"]) < 2e-3 and truth["impacts"][k]["plate"] == imp["plate"]:
            err.append(imp["cor"] - truth["impacts"][k]["cor"])
            z.append(err[-1] / imp["cor_std"])
    return np.array(err), np.array(z)


def _free_friction(doc: dict) -> tuple[np.ndarray, np.ndarray]:
    rows = [(f["friction_n"], f["friction_std_n"]) for f in doc["flights"] if f["friction_n"] is not None]
    return np.array([r[0] for r in rows]), np.array([r[1] for r in rows])


# ------------------------------------------------------------------ rig.yaml
def _rig_mapping(campaign) -> dict:
    return yaml.safe_load((campaign["src"] / "axis45" / "rig.yaml").read_text())


def test_rig_yaml_declares_the_orientation_and_refuses_one_out_of_range(campaign):
    data = _rig_mapping(campaign)
    assert data["setup"] == {"axis_tilt_deg": 45.0}             # what vibro synth --axis-tilt-deg wrote
    rig = parse_rig(data, "rig.yaml")
    assert rig.g_axis_mps2 == pytest.approx(G_MPS2 * math.cos(math.radians(45.0)), rel=1e-12)
    assert parse_rig({**data, "setup": {"axis_tilt_deg": 90}}).g_axis_mps2 == 0.0
    vertical = {k: v for k, v in data.items() if k != "setup"}
    assert parse_rig(vertical).setup.axis_tilt_deg == 0.0         # optional: absent is vertical
    for bad in (90.5, -1, 180, "vertical", True):
        with pytest.raises(RigError, match=r"setup\.axis_tilt_deg"):
            parse_rig({**data, "setup": {"axis_tilt_deg": bad}}, "rig.yaml")
    with pytest.raises(RigError, match=r"setup\.axis_tilt"):       # a misspelt key is refused, not ignored
        parse_rig({**data, "setup": {"axis_tilt": 45}}, "rig.yaml")


def test_synth_refuses_a_tilt_out_of_range(tmp_path, capsys):
    assert main(["synth", "--out", str(tmp_path / "r"), "--axis-tilt-deg", "95", "--frames", "20",
                 "--no-progress"]) == 2
    assert "axis_tilt_deg" in capsys.readouterr().err


# ------------------------------------------------------------------ declared 45 deg
def test_declared_45_is_a_property_of_the_rig_not_a_finding(campaign):
    doc, weight = campaign["docs"][45], WEIGHT_N
    assert doc["identification"]["axis_gravity_mps2"] == pytest.approx(G_MPS2 * math.cos(math.radians(45)))
    # the synthetic rig has no friction: every free flight's Eq. 17 force is zero within its sigma or the floor
    # (the old analysis gave m g (1 - cos 45) = 29 % of the weight on every flight)
    f, sd = _free_friction(doc)
    assert f.size >= 20
    assert np.all(np.abs(f) <= np.maximum(K_SIGMA * sd, FLOOR_OF_WEIGHT * weight)), f / weight
    assert abs(f.mean()) <= FLOOR_OF_WEIGHT * weight
    assert not any(x["effect"] == "gravity_tilt" for x in doc["discrepancy"]["findings"])


def test_declared_45_cor_as_good_as_vertical(campaign):
    errs = {}
    for tilt in (0, 45):
        err, z = _matched_cor_errors(campaign["docs"][tilt], campaign["truths"][tilt])
        assert err.size >= 20 and {"top", "bottom"} <= {i["plate"] for i in campaign["docs"][tilt]["impacts"]}
        assert np.max(np.abs(z)) < K_SIGMA, (tilt, z)                # each impact within its own sigma
        errs[tilt] = float(np.mean(np.abs(err)))
    # the tilted rig's COR as accurate as the vertical one's (both set by the DIC noise): within 2x, or 5e-5
    assert errs[45] <= 2.0 * errs[0] + 5e-5, errs


def test_declared_45_with_a_true_50_reports_the_total_tilt_and_corrects_the_friction(declared_45_true_50):
    truth, doc = declared_45_true_50
    tilts = [f for f in doc["discrepancy"]["findings"] if f["effect"] == "gravity_tilt"]
    assert len(tilts) == 1
    t = tilts[0]
    # the total tilt from vertical: 0.5 deg is g (cos 50 - cos 50.5) = 0.5 % of g, what a scale or DIC bias could
    # make; its own sigma is far smaller
    assert t["parameters"]["tilt_deg"] == pytest.approx(50.0, abs=0.5)
    assert t["undeclared_tilt_deg"] == pytest.approx(5.0, abs=0.5)
    assert "beyond the declared setup.axis_tilt_deg 45" in t["where"]
    weight = WEIGHT_N
    f, sd = _free_friction(doc)
    paper = np.array([x["friction_paper_n"] for x in doc["flights"] if x["friction_n"] is not None])
    # Eq. 17 against the declared gravity holds the undeclared tilt's force m g (cos 45 - cos 50), 6.4 % of the
    # weight, on every flight; the results subtract it and say so
    expected = weight * (math.cos(math.radians(45)) - math.cos(math.radians(50)))
    assert np.median(paper) == pytest.approx(expected, rel=0.05)
    assert np.all(np.abs(paper) < 0.1 * weight)                  # never the 29 % of a vertical assumption
    assert np.all(np.abs(f) <= np.maximum(K_SIGMA * sd, FLOOR_OF_WEIGHT * weight)), f / weight
    assert {x.get("friction_method") for x in doc["flights"] if x["friction_n"] is not None} == {"gravity_tilt"}
    assert doc["friction_model"]["force_subtracted_n"] == pytest.approx(expected, rel=0.05)
    err, z = _matched_cor_errors(doc, truth)
    assert err.size >= 20 and np.max(np.abs(z)) < K_SIGMA


# ------------------------------------------------------------------ horizontal
def test_horizontal_rig_measures_impacts_on_both_plates(campaign):
    # the regime allows it: with the drive at 40 m/s^2 the ball crosses the cavity once per half period, its
    # flights straight lines plus the guide rods' friction; impacts are the kinks where the velocity reverses
    doc, truth = campaign["docs"][90], campaign["truths"][90]
    assert doc["identification"]["axis_gravity_mps2"] == 0.0
    plates = [i["plate"] for i in doc["impacts"]]
    assert plates.count("top") >= 8 and plates.count("bottom") >= 8
    err, z = _matched_cor_errors(doc, truth)
    assert err.size == len(doc["impacts"]) and np.max(np.abs(z)) < K_SIGMA, z
    assert np.max(np.abs(err)) < 1e-3                               # the COR floor
    # the guide rods' friction, per flight (Eq. 17 with no gravity along the axis) and as the finding
    f, sd = _free_friction(doc)
    sign = np.array([1.0 if x["direction"] == "down" else -1.0 for x in doc["flights"] if x["friction_n"] is not None])
    assert np.all(np.abs(f - sign * GUIDE_RODS_N) <= K_SIGMA * sd + FLOOR_OF_WEIGHT * WEIGHT_N)
    found = {x["effect"]: x for x in doc["discrepancy"]["findings"]}
    assert set(found) == {"coulomb_friction"}
    assert found["coulomb_friction"]["parameters"]["force_n"] == pytest.approx(GUIDE_RODS_N, rel=0.02)


def test_a_horizontal_rig_described_as_vertical_is_refused_naming_the_key(campaign, tmp_path, capsys):
    # the silently wrong case before: exit 0, 0 impacts, "findings: none"
    src = campaign["src"] / "axis90"
    rec = tmp_path / "rec"
    rec.mkdir()
    shutil.copytree(src / "frames", rec / "frames")
    data = yaml.safe_load((src / "rig.yaml").read_text())
    data.pop("setup")
    (rec / "rig.yaml").write_text(yaml.safe_dump(data))
    track = campaign["out"] / "axis90" / "dic.csv"
    rc = main(["analyze", str(rec), "--out", str(tmp_path / "out"), "--track", str(track), "--no-progress",
               "--no-report"])
    err = capsys.readouterr().err
    assert rc == 2 and "setup.axis_tilt_deg" in err
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert doc["consistency"]["refused"] and doc["impacts"] == []
    finding = next(f for f in doc["consistency"]["findings"] if f["check"] == "axis_gravity")
    assert finding["keys"] == ["setup.axis_tilt_deg"]
    assert finding["evidence"]["implied_axis_tilt_deg"] > 60.0     # the flights barely fall: far from vertical


def test_declared_horizontal_with_a_true_88_finds_the_tilt_short_of_horizontal(tmp_path):
    # at 90 deg the tilt term is a force along the axis either way: here gravity pulls towards the lower plate
    # (g cos 88 = 0.34 m/s^2), a negative change against the declared 0, which non-negative least squares alone
    # would have clamped away
    truth = _synth(tmp_path / "rec", 90, "--effect", "gravity_tilt", "--param", "tilt_deg=88",
                   "--effect", "coulomb_friction", "--param", f"force_n={GUIDE_RODS_N}")
    assert main(["analyze", str(tmp_path / "rec"), "--out", str(tmp_path / "out"), "--no-progress",
                 "--no-report"]) == 0
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    found = {x["effect"]: x for x in doc["discrepancy"]["findings"]}
    assert set(found) == {"coulomb_friction", "gravity_tilt"}
    assert found["gravity_tilt"]["parameters"]["tilt_deg"] == pytest.approx(88.0, abs=0.5)
    assert found["gravity_tilt"]["undeclared_tilt_deg"] == pytest.approx(-2.0, abs=0.5)
    assert found["coulomb_friction"]["parameters"]["force_n"] == pytest.approx(GUIDE_RODS_N, rel=0.02)
    # each flight's friction, the tilt's force taken out: the guide rods' alone, against the motion
    f, sd = _free_friction(doc)
    sign = np.array([1.0 if x["direction"] == "down" else -1.0 for x in doc["flights"] if x["friction_n"] is not None])
    assert np.all(np.abs(f - sign * GUIDE_RODS_N) <= K_SIGMA * sd + FLOOR_OF_WEIGHT * WEIGHT_N)
    err, z = _matched_cor_errors(doc, truth)
    assert err.size >= 16 and np.max(np.abs(z)) < K_SIGMA


def test_no_impacts_is_never_reported_as_no_findings():
    lines = findings_lines({"baseline_deviation": None, "findings": [], "final_deviation": None,
                            "skipped": "discrepancy analysis skipped: no impacts identified (recording: still)"})
    assert lines == ["findings: not analysed: discrepancy analysis skipped: no impacts identified (recording: still)"]


# ------------------------------------------------------------------ the Fig. 11 study
def test_campaign_orientation_figure_holds_the_three_orientations(campaign):
    out = campaign["out"]
    doc = json.loads((out / "campaign.json").read_text())
    groups = doc["orientation"]
    assert [g["axis_tilt_deg"] for g in groups] == [0.0, 45.0, 90.0]
    for g in groups:
        tilt = int(g["axis_tilt_deg"])
        assert g["runs"] == [f"axis{tilt}"]
        for plate in ("top", "bottom"):
            c = g["cor"][plate]
            # the group's mean is the measured impacts' truth within the COR floor (each impact is off ~1e-4)
            measured = [i for i in campaign["docs"][tilt]["impacts"] if i["plate"] == plate]
            t_true = np.array([i["t"] for i in campaign["truths"][tilt]["impacts"]])
            true = [campaign["truths"][tilt]["impacts"][int(np.argmin(np.abs(t_true - i["t"])))]["cor"]
                    for i in measured]
            assert c["n"] == len(measured) >= 8
            assert abs(c["mean"] - float(np.mean(true))) < 1e-3
            # the interval is the mean's: t(0.975, n - 1) ~ 2.2 times a sample std of the 0.015 scatter / sqrt(n)
            assert c["ci95_low"] < c["mean"] < c["ci95_high"]
            assert 1.0 < c["ci95_half_width"] / (SCATTER / math.sqrt(c["n"])) < 4.0
    assert doc["figures"]["cor_by_orientation"] == "cor_by_orientation.png"
    import matplotlib.image

    img = matplotlib.image.imread(out / "cor_by_orientation.png")
    assert img.shape[0] > 200 and img.shape[1] > 400 and img[..., :3].std() > 0.01
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 3
    rows = (out / "campaign.csv").read_text().splitlines()
    assert rows[0].split(",")[6] == "axis_tilt_deg"
