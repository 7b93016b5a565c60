"""``vibro prove`` end to end: rendered synthetic recordings, DIC, identification and the discrepancy
analysis through the ``vibro analyze`` CLI on the recording directory only, scored against the truth files.

8 cases of 300 frames (about 90 s on one core): every effect family once and a control, drawn from the
documented ranges (vibro_sim/discrepancy/prove.py). The issue's goals are asserted as stated: >= 95 % of
effects identified (here: all 7), no finding on the control, main parameter within 15 %, D after within
1.5x of the true model's D on the same data.
"""

from __future__ import annotations

import json

import pytest

from vibro_bringup.cli import main
from vibro_eval.prove import FAMILIES, draw_cases, prove


@pytest.fixture(scope="module")
def proof(tmp_path_factory):
    work = tmp_path_factory.mktemp("prove")
    return prove(cases=8, seed=3, out=work, frames=300, sindy=True), work


def test_draws_cover_every_family_and_stay_in_range():
    specs = draw_cases(16, seed=5, frames=400)
    assert {s.family for s in specs[:8]} == set(FAMILIES)
    for s in specs:
        assert 20.0 <= s.frequency_hz <= 24.0 and 25.0 <= s.accel_ms2 <= 32.0 and 1.0 <= s.noise_gray <= 4.0
        if s.family == "coulomb_friction":
            assert 6e-5 <= s.effects[s.family]["force_n"] <= 3e-4
        if s.family == "asymmetric_restitution":
            p = s.effects[s.family]
            assert p["cor_bottom"] > p["cor_top"]   # as in the paper's Table 2


def test_goals_met_blind(proof):
    res, work = proof
    v = res["vibro"]
    assert v["failed_cases"] == 0, [r.get("error") for r in res["rows"]]
    assert v["identified_pct"] >= 95.0, v["confusion"]
    assert v["spurious_findings_on_effect_cases"] == 0, v["confusion"]
    assert v["controls_without_finding"] == v["controls"] >= 1
    assert v["parameter_error_max_pct"] <= 15.0
    assert v["d_final_over_true_max"] <= 1.5
    assert (work / "proof.json").is_file()
    # every case ran the CLI on the recording only: its results.json exists next to the truth file
    for r in res["rows"]:
        out = work / f"case{r['case']:03d}_out" / "results.json"
        assert "discrepancy" in json.loads(out.read_text())


def test_vibro_beats_pysindy_on_the_same_data(proof):
    pytest.importorskip("pysindy")
    res, _ = proof
    v, s = res["vibro"], res["sindy"]
    assert v["identified"] >= s["identified"]
    assert v["spurious_findings_on_effect_cases"] <= s["spurious_findings_on_effect_cases"]
    assert (v["identified"] - v["spurious_findings_on_effect_cases"]) > (
        s["identified"] - s["spurious_findings_on_effect_cases"])


def test_prove_cli_bad_arguments_are_one_line_errors(capsys, tmp_path):
    assert main(["prove", "--cases", "0", "--out", str(tmp_path)]) == 2
    assert "--cases" in capsys.readouterr().err
    assert main(["prove", "--frames", "50", "--out", str(tmp_path)]) == 2
    assert "--frames" in capsys.readouterr().err
