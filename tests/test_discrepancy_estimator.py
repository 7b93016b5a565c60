"""The discrepancy engine as an estimator over the domain model (issue 12, item 3): its input is the
identification as vibro_model types (no results.json mapping in between), its findings are typed
(vibro_model.results.DiscrepancyFinding) and survive model -> results.json keys -> model and
model -> message -> model; the replay core (vibro_sim.measured) takes the same types, SI inside.

Cases from tests/discrepancy_cases.py (synthetic rig physics, DIC noise 0.25 um, vibro_fit identification).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import pytest
from discrepancy_cases import make_case

from vibro_discrepancy import CandidateLibrary, DiscrepancyEstimator, run_discrepancy
from vibro_discrepancy.data import measured_from_document
from vibro_discrepancy.library import GravityTilt
from vibro_model.results import Discrepancy, DiscrepancyFinding, Flight, Impact, ResultsDocument, StructureMotion


@pytest.fixture(scope="module")
def harmonics_case():
    sections, track, rig, _ = make_case({"structure_harmonics": {"h2_ratio": 0.03, "h3_ratio": 0.01}}, seed=15)
    doc = ResultsDocument.from_dict(sections)
    return sections, doc, track, rig, run_discrepancy(doc, track, rig)


@pytest.fixture(scope="module")
def drag_outside_library():
    # viscous drag with only the tilt in the library: the drag must come out unexplained
    sections, track, rig, _ = make_case({"viscous_drag": {"coefficient_ns_per_m": 3e-4}}, seed=31)
    meas = measured_from_document(ResultsDocument.from_dict(sections), track, rig)
    return DiscrepancyEstimator(CandidateLibrary(flight_terms=(GravityTilt(),))).fit(meas)


def _close(a, b, rel: float, path: str = "") -> list[str]:
    """Paths where two JSON values differ (numbers beyond ``rel``, anything else at all)."""
    if isinstance(a, dict) and isinstance(b, dict):
        if list(a) != list(b):
            return [f"{path}: keys {list(a)} != {list(b)}"]
        return [d for k in a for d in _close(a[k], b[k], rel, f"{path}.{k}")]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} != {len(b)} items"]
        return [d for k, (x, y) in enumerate(zip(a, b)) for d in _close(x, y, rel, f"{path}[{k}]")]
    if isinstance(a, float) and isinstance(b, float):
        return [] if math.isclose(a, b, rel_tol=rel, abs_tol=1e-15) else [f"{path}: {a!r} != {b!r}"]
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


def test_engine_input_is_the_domain_model(harmonics_case):
    sections, doc, track, rig, run = harmonics_case
    meas = run.measured
    assert isinstance(meas.structure, StructureMotion) and all(isinstance(i, Impact) for i in meas.impacts)
    assert all(isinstance(f.flight, Flight) for f in meas.flights)
    # SI inside: the identified amplitude (m) is the mapping's amplitude_mm / 1000
    assert meas.structure.amplitude_m == pytest.approx(abs(sections["structure"]["amplitude_mm"]) / 1000, rel=1e-12)
    # a results.json mapping (read through the codec) gives the same block: the mapping carries mm, the model
    # m, so the two differ by rounding in the last place of the input, amplified by the iterative fits to
    # < 1e-6 relative (the physical tolerances of the engine tests are percent)
    from_mapping = run_discrepancy(sections, track, rig).document
    assert _close(run.document, from_mapping, 1e-6) == []
    assert [f["effect"] for f in run.document["findings"]][0] == "structure_harmonics"


def test_typed_findings_round_trip_through_results_json(harmonics_case, drag_outside_library):
    for run in (harmonics_case[-1], drag_outside_library):
        assert isinstance(run.result, Discrepancy) and run.result.findings
        assert run.document == run.result.to_dict()
        text = json.dumps(run.document, allow_nan=False)  # plain, strict JSON
        assert Discrepancy.from_dict(json.loads(text)) == run.result
        for f in run.result.findings:
            assert isinstance(f, DiscrepancyFinding)
            assert DiscrepancyFinding.from_dict(json.loads(json.dumps(f.to_dict()))) == f
    effects = [f.effect for f in drag_outside_library.result.findings]
    assert "unexplained" in effects and "viscous_drag" not in effects
    unexplained = drag_outside_library.result.findings[effects.index("unexplained")]
    assert unexplained.parameters == {} and "parameters_std" not in unexplained.to_dict()
    assert "mismatches" in unexplained.details


def test_typed_findings_round_trip_through_messages(harmonics_case, drag_outside_library):
    from vibro_ros.convert import finding_from_message, finding_to_message

    findings = harmonics_case[-1].result.findings + drag_outside_library.result.findings
    for k, f in enumerate(findings):
        back = finding_from_message(finding_to_message(f, k, 0.5))
        # the message carries the contract fields; the engine's extras stay in results.json
        assert back == replace(f, details={}), f.effect


def test_replay_inputs_from_domain_types():
    from vibro_sim.measured import replay_inputs

    # structure Y_s = A sin(2 pi f t) (m), ball parabola Y_b = a t^2 + b t + c (m) from t0 = 0.01 s
    A, f_hz, b_mps, c_m, offset_m = 1e-3, 20.0, 0.3, 2e-4, -1e-4
    s = StructureMotion(amplitude_m=A, frequency_hz=f_hz, phase_rad=0.0, offset_m=0.0, ball_offset_m=offset_m)
    flights = [Flight(index=0, t_first_frame_s=0.0, t_last_frame_s=0.009, a_mps2=-4.905, b_mps=0.0, c_m=0.0,
                      direction="up", friction_n=None, friction_std_n=None, rms_residual_m=None, n_points=5,
                      free=False),
               Flight(index=1, t_first_frame_s=0.01, t_last_frame_s=0.05, a_mps2=-4.905, b_mps=b_mps, c_m=c_m,
                      direction="up", friction_n=1e-4, friction_std_n=1e-5, rms_residual_m=1e-7, n_points=40,
                      free=True),
               Flight(index=2, t_first_frame_s=0.051, t_last_frame_s=0.08, a_mps2=-4.0, b_mps=0.0, c_m=0.0,
                      direction="down", friction_n=None, friction_std_n=None, rms_residual_m=None, n_points=5,
                      free=False)]  # not free: no force
    impacts = [Impact(index=0, t_s=0.0095, plate="bottom", cor=0.7, cor_std=0.01, v_ball_before_mps=-0.3,
                      v_ball_after_mps=0.3, v_structure_mps=0.0),
               Impact(index=1, t_s=0.05, plate="top", cor=0.6, cor_std=0.01, v_ball_before_mps=0.2,
                      v_ball_after_mps=-0.2, v_structure_mps=0.0), Impact(index=2, t_s=None, plate="top", cor=None,
                                                                          cor_std=None, v_ball_before_mps=None,
                                                                          v_ball_after_mps=None, v_structure_mps=None)]
    inputs = replay_inputs(s, flights, impacts, free_play_m=2e-3, t_end_s=0.1)
    t0 = 0.01
    w = 2 * math.pi * f_hz
    assert inputs.t_start_s == t0
    assert inputs.y_rel_m == pytest.approx(-4.905 * t0 ** 2 + b_mps * t0 + c_m + offset_m - A * math.sin(w * t0),
                                           abs=1e-15)
    assert inputs.v_rel_mps == pytest.approx(-9.81 * t0 + b_mps - A * w * math.cos(w * t0), abs=1e-12)
    # the impact before the start and the one without a time are not replayed; free flight's force only
    assert inputs.impact_times_s == [0.05] and inputs.impact_cors == [0.6] and inputs.flight_forces_n == [1e-4, 0.0]
    with pytest.raises(ValueError, match="structure sine"):
        replay_inputs(replace(s, frequency_hz=None), flights, impacts, 2e-3, 0.1)
