"""``vibro prove`` end to end: rendered synthetic recordings, DIC, identification and the discrepancy
analysis through the ``vibro analyze`` CLI on the recording directory only, scored against the truth files.

8 cases of 300 frames (about 100 s on one core), every one with per-impact COR scatter 0.015 (the paper's
Fig. 14-16; issue 13), read noise 1-3 gray levels and motion blur on about half: six catalogue families,
one out-of-catalogue effect (the synth's ``plate_step``) and a control, drawn from the documented ranges
(vibro_eval/prove.py). ``coulomb_friction`` is the family left out here: tests/test_discrepancy_engine.py
identifies it (and every other family) and tests/test_unexplained.py names it under the same 0.015 scatter.
The issue's goals are asserted as stated: >= 95 % of effects identified (here: all 7), the invented effect
reported as ``unexplained`` where the truth has it, no finding on the control, main parameter within 15 %,
each correct finding improving the model (D_r lower; a COR law: COR variance explained
above chance), D_r after within 1.5x of the true model's D_r
on the same data, and per-impact COR error against the truth <= 0.002 with an effect, <= 0.001 without.
"""

from __future__ import annotations

import json

import pytest

from vibro_app.cli import main
from vibro_eval.prove import (
    CONTROL,
    EFFECTS,
    EVIDENCE,
    FAMILIES,
    GOALS,
    INVENTED,
    Draws,
    ProofCases,
    draw_cases,
    draw_evidence,
    prove,
)

SCATTER = 0.015
LEFT_OUT = "coulomb_friction"
CI_DRAWS = Draws(cor_scatter=(SCATTER, SCATTER), noise_gray=(1.0, 3.0), blur_share=0.5, magnitudes=1, controls=1,
                 catalogue=tuple(f for f in EFFECTS if f != LEFT_OUT), invented=("plate_step",))


@pytest.fixture(scope="module")
def proof(tmp_path_factory):
    work = tmp_path_factory.mktemp("prove")
    return prove(ProofCases(seed=3, frames=300, draws=CI_DRAWS), out=work, sindy=True), work


def test_draws_cover_every_family_and_stay_in_range():
    specs = draw_cases(16, seed=5, frames=400)
    assert {s.family for s in specs[:8]} == set(FAMILIES)
    for s in specs:
        assert 20.0 <= s.frequency_hz <= 24.0 and 25.0 <= s.accel_mps2 <= 32.0 and 1.0 <= s.noise_gray <= 4.0
        assert s.cor_scatter == 0.0 and not s.blur
        if s.family == "coulomb_friction":
            assert 6e-5 <= s.effects[s.family]["force_n"] <= 3e-4
        if s.family == "asymmetric_restitution":
            p = s.effects[s.family]
            assert p["cor_bottom"] > p["cor_top"]   # as in the paper's Table 2
    # scatter and blur come from their own stream: the legacy draws do not move
    again = draw_cases(16, seed=5, frames=400, draws=Draws(cor_scatter=(0.01, 0.02), blur_share=0.5))
    assert [(s.family, s.effects, s.seed, s.noise_gray) for s in again] == \
        [(s.family, s.effects, s.seed, s.noise_gray) for s in specs]
    assert all(0.01 <= s.cor_scatter <= 0.02 for s in again) and 0 < sum(s.blur for s in again) < 16


def test_evidence_draws_each_family_at_two_magnitudes():
    specs = draw_evidence(seed=7, frames=1000)
    fams = [s.family for s in specs]
    assert len(specs) == 2 * (len(EFFECTS) + len(INVENTED)) + EVIDENCE.controls
    assert fams.count(CONTROL) == 3 and all(fams.count(f) == 2 for f in EFFECTS + INVENTED)
    for s in specs:
        assert 0.01 <= s.cor_scatter <= 0.02 and 1.0 <= s.noise_gray <= 3.0
    assert 0 < sum(s.blur for s in specs) < len(specs)
    # magnitude 1 is the stronger half of the main parameter's range
    main = {"coulomb_friction": "force_n", "viscous_drag": "coefficient_ns_per_m",
            "quadratic_drag": "coefficient_ns2_per_m2", "gravity_tilt": "tilt_deg", "structure_harmonics": "h2_ratio",
            "velocity_dependent_restitution": "slope_s_per_m", "structure_tone": "tone_amplitude_um",
            "plate_step": "step_um"}
    for fam, key in main.items():
        lo, hi = sorted((s for s in specs if s.family == fam), key=lambda s: s.magnitude)
        assert lo.effects[fam][key] <= hi.effects[fam][key], fam
    lo, hi = sorted((s for s in specs if s.family == "asymmetric_restitution"), key=lambda s: s.magnitude)
    assert lo.effects["asymmetric_restitution"]["cor_top"] >= hi.effects["asymmetric_restitution"]["cor_top"]
    for s in specs:
        if s.family == "cor_drift":   # the COR changes by 0.05-0.15 over the 1 s recording
            assert 0.05 <= abs(s.effects["cor_drift"]["drift_per_s"]) * 1.0 <= 0.15
        if s.family == "plate_step":  # inside the recording, 4 drive cycles from either end
            t = s.effects["plate_step"]["step_time_s"]
            assert 4.0 / s.frequency_hz <= t <= 1.0 - 4.0 / s.frequency_hz


def test_goals_met_blind(proof):
    res, work = proof
    v = res["vibro"]
    assert v["failed_cases"] == 0, [r.get("error") for r in res["rows"]]
    assert v["cases"] == 8 and v["controls"] == 1 and v["out_of_catalogue"] == 1
    assert v["identified_pct"] >= GOALS["identified_pct"], v["confusion"]
    assert v["spurious_findings_on_effect_cases"] == 0, v["confusion"]
    assert v["controls_without_finding"] == v["controls"]
    assert v["parameter_error_max_pct"] <= GOALS["parameter_error_pct"]
    assert (work / "proof.json").is_file()
    # every case ran the CLI on the recording only: its results.json exists next to the truth file
    for r in res["rows"]:
        out = work / f"case{r['case']:03d}_out" / "results.json"
        assert "discrepancy" in json.loads(out.read_text())
        assert r["spec"]["cor_scatter"] == SCATTER


def test_out_of_catalogue_is_unexplained_where_the_truth_has_it(proof):
    res, _ = proof
    (row,) = [r for r in res["rows"] if r["family"] == "plate_step"]
    assert row["found"] == ["unexplained"], row["found"]
    assert row["score"]["located"] == {"plate_step": True}


def test_each_correct_finding_improves_the_model(proof):
    """Structure and flight findings lower the restarted deviation D_r; a COR law cannot move D_r (the
    run restarts from the measured state after each impact), it must explain a share of the per-impact
    COR variance above what a law of as many parameters explains on pure noise."""
    res, _ = proof
    for r in res["rows"]:
        for f in r["findings"]:
            if f["correct"] and f["effect"] != "unexplained":
                assert f["lowered"], (r["family"], f)
                if f["measure"] == "D_r":
                    assert f["after"] < f["before"]
                else:
                    assert f["cor_variance_share"] > f["chance_share"] > 0
        if r["family"] in EFFECTS:
            # D_r of the final model within 1.5x of what the true model reaches on the same data
            # (the paper's free-running D measures the COR scatter's chaos, not the model: issue 13.1)
            assert r["deviation"]["final_over_true_restarted"] <= GOALS["d_ratio"], (r["family"], r["deviation"])


def test_per_impact_cor_error_against_the_truth(proof):
    """The issue's goals: <= 0.002 with an effect (the final model re-measures the impacts), <= 0.001
    without; every measured impact matched to a truth impact of the same plate within a frame."""
    res, _ = proof
    for r in res["rows"]:
        ce = r["cor_error"]
        goal = GOALS["cor_error_controls"] if r["family"] == CONTROL else GOALS["cor_error_effects"]
        assert ce["n"] >= 8 and ce["unmatched"] == 0, (r["family"], ce)
        assert ce["max_abs"] <= goal, (r["family"], ce)
        # the contact's scatter (0.015) is far above the identification's COR noise: reported as random
        assert r["contact_scatter"]["exceeds_noise"] is True, (r["family"], r["contact_scatter"])
    # with harmonics the paper's pure-sine structure velocity is off (issue 13.2: ~0.03 at 5 %); the
    # re-identified CORs must be better than the paper's on that case
    (h,) = [r for r in res["rows"] if r["family"] == "structure_harmonics"]
    assert h["cor_error"]["max_abs"] < h["cor_error"]["max_abs_paper"]


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
    assert main(["prove", "--cases", "4", "--magnitudes", "2", "--out", str(tmp_path)]) == 2
    assert "--magnitudes" in capsys.readouterr().err
    assert main(["prove", "--cor-scatter", "0.02,0.01", "--out", str(tmp_path)]) == 2
    assert "--cor-scatter" in capsys.readouterr().err
    assert main(["prove", "--cor-scatter", "abc", "--out", str(tmp_path)]) == 2
    assert "--cor-scatter" in capsys.readouterr().err
    assert main(["prove", "--blur-share", "2", "--out", str(tmp_path)]) == 2
    assert "--blur-share" in capsys.readouterr().err
    assert main(["prove", "--invented", "--out", str(tmp_path)]) == 2
    assert "--invented" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())   # nothing synthesized on bad input
