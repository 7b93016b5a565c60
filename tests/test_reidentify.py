"""Issue 13 item 2: the physics the discrepancy analysis found corrects the measurement.

Real synthetic recordings (``vibro synth``, per-impact COR scatter 0.015 as the paper's Fig. 14-16),
analysed by the real ``vibro analyze`` in a separate process (it never sees the truth file); the
per-impact CORs in results.json are scored against DIR.truth.json.

Tolerances. The noise: 2 gray levels of read noise on a 160x480 px speckle gives DIC position noise of
a few um, so a flight of ~20 frames measures the ball's velocity at an impact to ~1e-4 m/s and the COR
to ~1e-4 (the propagated ``cor_std`` of these recordings: 2e-5 to 1e-4). The issue's bound 0.002 per
impact is therefore > 10 noise sigmas: what it leaves room for is model bias, which is what this
checks. The bias of the paper's estimate without the correction:
- structure_harmonics (h2 = 0.05, h3 = 0.02 of A = 1.41 mm at 22 Hz): the pure sine misses up to
  A w (2 h2 + 3 h3) = 0.031 m/s of structure velocity at an impact; de = dv_s (1 + e) / |v_rel| with
  |v_rel| ~ 0.6 m/s gives up to ~0.09, so the paper's CORs are off by several 0.01;
- quadratic_drag (k = 5e-4 N s^2/m^2 on 0.182 mg, |v| < 0.5 m/s): k v^2 / m up to 0.7 m/s^2 against g,
  bending each parabola so that its end velocities are off by ~1e-3 m/s: COR off by up to ~0.005.
The control (no effect) must keep the paper's values exactly (nothing found, nothing changed) and
score within 0.001 (10 noise sigmas).
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
VIBRO = [sys.executable, "-m", "vibro_app.cli"]
FRAMES = "300"
SCATTER = "0.015"
TOL_EFFECT = 0.002     # issue 13: per-impact COR error with an effect found
TOL_CONTROL = 0.001    # issue 13: per-impact COR error without effects
CASES = {
    "harmonics": ["--effect", "structure_harmonics"],
    "quadratic": ["--effect", "quadratic_drag", "--param", "coefficient_ns2_per_m2=5e-4"],
    "control": ["--effect", "none"],
}


def _vibro(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    return subprocess.run([*VIBRO, *args], capture_output=True, text=True, timeout=300, env=env, cwd=ROOT)


@pytest.fixture(scope="module")
def analysed(tmp_path_factory) -> dict[str, dict]:
    """Each case: synthesized (seed 11, 300 frames, COR scatter 0.015) and analysed by the CLI."""
    base = tmp_path_factory.mktemp("reidentify")
    out = {}
    for name, effect in CASES.items():
        rec, res = base / name, base / f"{name}_out"
        p = _vibro("synth", "--out", str(rec), "--frames", FRAMES, "--seed", "11", "--cor-scatter", SCATTER,
                   "--no-accel", "--no-progress", *effect)
        assert p.returncode == 0, p.stderr
        a = _vibro("analyze", str(rec), "--out", str(res), "--no-progress", *(["--no-report"] if name != "harmonics"
                                                                             else []))
        assert a.returncode == 0, a.stderr
        out[name] = {"results": json.loads((res / "results.json").read_text()),
                     "truth": json.loads(Path(f"{rec}.truth.json").read_text()), "out": res}
    return out


def _errors(case: dict, cor_key: str, t_key: str) -> tuple[np.ndarray, np.ndarray]:
    """(COR error against the true impact nearest in time, that time difference in s) per impact."""
    truth = case["truth"]["impacts"]
    t_true = np.array([i["t"] for i in truth])
    cor_true = np.array([i["cor"] for i in truth])
    errs, dts = [], []
    for imp in case["results"]["impacts"]:
        j = int(np.argmin(np.abs(t_true - imp[t_key])))
        errs.append(imp[cor_key] - cor_true[j])
        dts.append(imp[t_key] - t_true[j])
    return np.array(errs), np.array(dts)


@pytest.mark.parametrize("name,effect", [("harmonics", "structure_harmonics"), ("quadratic", "quadratic_drag")])
def test_the_effect_found_corrects_every_impacts_cor(analysed, name, effect) -> None:
    case = analysed[name]
    r = case["results"]
    assert effect in [f["effect"] for f in r["discrepancy"]["findings"]]
    assert r["impacts_model"]["cor_method"] == effect and r["impacts_model"]["effects"] == [effect]
    impacts = r["impacts"]
    assert len(impacts) >= 10
    assert all(i["cor_method"] == effect for i in impacts), [i["cor_method"] for i in impacts]
    assert r["impacts_model"]["n_reidentified"] == len(impacts)

    err, dt = _errors(case, "cor", "t")
    err_paper, _ = _errors(case, "cor_paper", "t_paper")
    assert np.all(np.abs(dt) < 1e-3)  # each impact matched to its true one (impacts are ~20 ms apart)
    assert np.max(np.abs(err)) <= TOL_EFFECT, err
    # the paper's Eq. 16 values beside them are measurably worse: outside the bound, and the correction
    # removes at least 80 % of their RMS error
    assert np.max(np.abs(err_paper)) > TOL_EFFECT
    assert np.sqrt(np.mean(err ** 2)) < 0.2 * np.sqrt(np.mean(err_paper ** 2))
    # the propagated sigma describes the corrected COR's error (RMS z-score within 3: not optimistic by
    # more than 3x; the shared force coefficients' uncertainty is left out of it)
    std = np.array([i["cor_std"] for i in impacts])
    assert np.all(std > 0)
    assert np.sqrt(np.mean((err / std) ** 2)) < 3.0
    # the impact times are the final model's: where its flights meet, within 5 t_std of the truth (or
    # 20 us, a frame's 1/50)
    t_std = np.array([i["t_std"] for i in impacts])
    assert np.all(np.abs(dt) <= np.maximum(5 * t_std, 20e-6))


def test_the_summary_statistics_and_flights_use_the_corrected_values(analysed) -> None:
    case = analysed["harmonics"]
    r = case["results"]
    for plate in ("top", "bottom"):
        cors = [i["cor"] for i in r["impacts"] if i["plate"] == plate]
        paper = [i["cor_paper"] for i in r["impacts"] if i["plate"] == plate]
        s = r["cor_summary"][plate]
        assert s["n"] == len(cors) and s["mean"] == pytest.approx(np.mean(cors), abs=1e-12)
        assert s["std"] == pytest.approx(np.std(cors, ddof=1), abs=1e-12)
        assert abs(np.mean(cors) - np.mean(paper)) > 1e-3  # the harmonics shift the paper's mean
        hist = r["cor_statistics"][plate]
        counts, edges = np.array(hist["histogram_counts"]), np.array(hist["histogram_edges"])
        assert counts.sum() == len(cors)
        assert edges[0] <= min(cors) and edges[-1] >= max(cors)
    # a flight's t_start/t_end are the impacts that open/close it: the corrected times
    flights = {f["index"]: f for f in r["flights"]}
    for imp in r["impacts"]:
        assert flights[imp["flight_after"]]["t_start"] == imp["t"]
        assert flights[imp["flight_before"]]["t_end"] == imp["t"]
    # impacts.csv carries the same values, the paper's beside them
    with open(case["out"] / "impacts.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [float(row["cor"]) for row in rows] == pytest.approx([i["cor"] for i in r["impacts"]], abs=1e-12)
    assert [float(row["cor_paper"]) for row in rows] == pytest.approx([i["cor_paper"] for i in r["impacts"]],
                                                                    abs=1e-12)
    assert "final model" in (case["out"] / "report.html").read_text()


def test_without_an_effect_the_paper_values_stay(analysed) -> None:
    case = analysed["control"]
    r = case["results"]
    assert [f["effect"] for f in r["discrepancy"]["findings"]] == []
    assert r["impacts_model"]["cor_method"] == "paper" and r["impacts_model"]["effects"] == []
    for imp in r["impacts"]:
        assert imp["cor_method"] == "paper"
        assert imp["cor"] == imp["cor_paper"] and imp["t"] == imp["t_paper"] and imp["cor_std"] == imp["cor_std_paper"]
    err, dt = _errors(case, "cor", "t")
    assert len(err) >= 10 and np.all(np.abs(dt) < 1e-3)
    assert np.max(np.abs(err)) <= TOL_CONTROL, err


def test_results_without_the_new_keys_still_read_and_new_ones_round_trip(analysed, tmp_path) -> None:
    from vibro_io.results_file import read_results

    data = analysed["harmonics"]["results"]
    path = tmp_path / "new.json"
    path.write_text(json.dumps(data))
    doc = read_results(path)
    assert doc.to_dict()["impacts"] == data["impacts"]
    assert doc.to_dict()["impacts_model"] == data["impacts_model"]
    # a document written before the keys existed
    old = json.loads(json.dumps(data))
    del old["impacts_model"]
    for imp in old["impacts"]:
        for key in ("cor_method", "cor_paper", "cor_std_paper", "t_paper"):
            del imp[key]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    doc = read_results(path)
    assert all(i.cor_method is None and i.cor_paper is None for i in doc.impacts)
    assert doc.to_dict()["impacts"] == old["impacts"]
    # a wrong type is refused naming the key
    bad = json.loads(json.dumps(data))
    bad["impacts"][2]["cor_paper"] = "0.7"
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    from vibro_model.codec import ResultsError

    with pytest.raises(ResultsError, match=r"impacts\[2\]\.cor_paper"):
        read_results(path)


def test_the_discrepancy_node_publishes_the_impacts_analyze_remeasures(analysed, tmp_path, ros_domain) -> None:
    """The graph path: the ``discrepancy`` node (its own process, over DDS) fed the identification that
    ``vibro analyze`` made (the fitter's messages) publishes on vibro/impacts_final_model the impacts
    analyze wrote, re-measured by the same module (equal to 1e-9)."""
    from discrepancy_dds import feed_case, run_discrepancy_node

    from vibro_io.dictrack import read_dic_csv

    case = analysed["quadratic"]
    r = case["results"]
    identified = [{**i, "t": i["t_paper"], "cor": i["cor_paper"], "cor_std": i["cor_std_paper"]} for i in r["impacts"]]
    sections = {"structure": r["structure"], "flights": r["flights"], "impacts": identified, "dic_bias": r["dic_bias"]}
    case_file = feed_case(tmp_path / "case.json", sections, read_dic_csv(case["out"] / "dic.csv"))
    run = run_discrepancy_node(case_file, case["out"].parent / "quadratic" / "rig.yaml",
                               "vibro_msgs/msg/ImpactEstimate", "vibro/impacts_final_model", count=len(identified))
    rows = {row["index"]: row for row in run.rows}
    assert sorted(rows) == [i["index"] for i in r["impacts"]], run.logs
    for imp in r["impacts"]:
        msg = rows[imp["index"]]
        assert msg["final"] is True
        for key, field in (("t", "t_s"), ("cor", "cor"), ("cor_std", "cor_std"), ("v_structure", "v_structure_m_per_s"),
                           ("v_ball_before", "v_ball_before_m_per_s"), ("v_ball_after", "v_ball_after_m_per_s")):
            assert msg[field] == pytest.approx(imp[key], abs=1e-9), (imp["index"], key)
    assert "Traceback" not in run.node_err
