"""The one results assembler (vibro_model.assemble): the rules every path to results.json shares, written once.

The stage outputs here are built by hand from a physically consistent toy run (a ball leaving each plate at
e times its approach speed, plates alternating), so each rule is checked against what it must do, not
against an earlier output: a refusal withholds the COR table and everything after the cross-checks, a run
that lost frames is incomplete with its loss said first, impacts measured again under the final model carry
the final CORs into the summary and the statistics, and the bag path (the same stages after a trip through
the ROS messages) gives the same document as the direct path.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from vibro_model.assemble import (
    PAPER,
    BallSpinStage,
    CompletenessStage,
    ConsistencyStage,
    DiscrepancyStage,
    Identified,
    LocalStructure,
    Reidentification,
    SimulationStage,
    StageOutputs,
    assemble_results,
    cor_statistics_section,
)
from vibro_model.results import (
    Discrepancy,
    DiscrepancyFinding,
    Flight,
    Impact,
    ResultsDocument,
    Simulation,
    StructureMotion,
)

N_IMPACTS = 12
HALF_PERIOD_S = 0.0227  # two impacts per drive cycle at 22 Hz


def _structure() -> StructureMotion:
    return StructureMotion(amplitude_m=3.0e-3, frequency_hz=22.0, phase_rad=0.3, offset_m=0.0, n_points=400)


def _impacts(cors: list[float]) -> list[Impact]:
    """Impact k between flights k and k+1: the ball arrives at 0.5 m/s relative to the plate and leaves at e
    times that (Eq. 16), the plate moving at v_s."""
    out = []
    for k, e in enumerate(cors):
        v_s = 0.05 * (-1) ** k
        sign = 1.0 if k % 2 == 0 else -1.0  # top plate: arrives moving up
        v_before = v_s + sign * 0.5
        v_after = v_s - sign * 0.5 * e
        out.append(Impact(index=k, t_s=0.03 + k * HALF_PERIOD_S, plate="top" if k % 2 == 0 else "bottom", cor=e,
                          cor_std=0.004, v_ball_before_mps=v_before, v_ball_after_mps=v_after, v_structure_mps=v_s,
                          t_std_s=3e-6, flight_before=k, flight_after=k + 1))
    return out


def _flights(n: int) -> list[Flight]:
    return [Flight(index=k, t_first_frame_s=0.011 + k * HALF_PERIOD_S, t_last_frame_s=0.029 + k * HALF_PERIOD_S,
                   a_mps2=-4.9, b_mps=0.1, c_m=0.0, direction="down" if k % 2 == 0 else "up", friction_n=-2e-5,
                   friction_std_n=3e-6, rms_residual_m=5e-7, n_points=18, free=True) for k in range(n)]


def _identified(cors: list[float] | None = None) -> Identified:
    rng = np.random.default_rng(7)
    cors = cors if cors is not None else list(0.7 + 0.01 * rng.standard_normal(N_IMPACTS))
    statements = [{"check": "free_play", "keys": ["structure.gap_mm"], "message": "measured free play 15.9 mm",
                   "blocks_physics": False},
                  {"check": "fps", "keys": ["camera.fps"], "message": "frame period differs", "blocks_physics": False}]
    return Identified(structure=_structure(), flights=_flights(N_IMPACTS + 1), impacts=_impacts(cors),
                      warnings=["flight 3: 2 frames rejected"],
                      sections={"regime": {"name": "two_impacts_per_cycle"}, "rig_consistency": statements})


def _refusal(*, friction: bool, frequency_cause: bool) -> ConsistencyStage:
    return ConsistencyStage(section={"refused": True, "findings": [], "checks": {}},
                            warnings=["consistency: COR outside [0, 1]"], refusal="COR outside [0, 1]",
                            withhold_friction=friction,
                            consequence_keys=frozenset({"structure.gap_mm", "ball.diameter_mm"}) if frequency_cause
                            else frozenset())


def _later_stages() -> dict:
    finding = DiscrepancyFinding("coulomb_friction", {"force_n": 2e-4}, "flights", 0.03, 0.004)
    return {"simulation": SimulationStage(simulation=Simulation.of_deviations({"cor_model": 0.03, "hertz_model": 0.05}),
                                          warnings=["simulation hertz_model: slow"]),
            "discrepancy": DiscrepancyStage(discrepancy=Discrepancy(0.03, [finding], 0.004)),
            "ball_spin": BallSpinStage(section={"available": True})}


def test_a_refused_run_withholds_the_cor_table_and_every_later_stage() -> None:
    stages = StageOutputs(recording="r", identified=_identified(), consistency=_refusal(friction=True,
                                                                                      frequency_cause=True),
                          **_later_stages())
    doc = assemble_results(stages)
    assert doc.impacts == [] and doc.cor_summary.top.n == doc.cor_summary.bottom.n == 0
    assert "cor_statistics" not in doc.sections and "ball_spin" not in doc.sections
    assert "impacts_model" not in doc.sections  # no re-identification of a refused run
    assert doc.complete is False and doc.warnings[0] == "refused: COR outside [0, 1]"
    # the simulation and discrepancy stages were given but a refused run never reached them
    assert doc.simulation.deviation("cor_model") is None and doc.discrepancy.findings == []
    assert not any(w.startswith("simulation") for w in doc.warnings)
    # friction withheld, the flights kept
    assert len(doc.flights) == N_IMPACTS + 1 and all(f.friction_n is None for f in doc.flights)
    # the free-play statement (a consequence of the wrong frequency) dropped with its warning; the other kept
    assert [r["check"] for r in doc.sections["rig_consistency"]] == ["fps"]
    # a refusal that is not about the friction nor the frequency keeps both
    doc = assemble_results(replace(stages, consistency=_refusal(friction=False, frequency_cause=False)))
    assert all(f.friction_n is not None for f in doc.flights)
    assert [r["check"] for r in doc.sections["rig_consistency"]] == ["free_play", "fps"]


def test_a_run_that_lost_frames_is_incomplete_and_says_so_first() -> None:
    lost = CompletenessStage(section={"frames_missing": 32}, warnings=["frames 100..131 have no DIC result"],
                             complete=False)
    doc = assemble_results(StageOutputs(recording="r", identified=_identified(), completeness=lost))
    assert doc.complete is False
    assert doc.warnings[:2] == ["frames 100..131 have no DIC result", "flight 3: 2 frames rejected"]
    assert next(iter(doc.sections)) == "completeness"
    whole = replace(lost, complete=True, warnings=())
    assert assemble_results(StageOutputs(recording="r", identified=_identified(), completeness=whole)).complete


def test_impacts_measured_again_carry_the_final_cors_into_the_summary_and_statistics() -> None:
    ident = _identified()
    # the final model measures every top impact 0.05 lower (a friction the paper's parabolas left in)
    remeasured = [replace(i, cor=i.cor - 0.05, t_paper_s=i.t_s) for i in ident.impacts if i.plate == "top"]
    stages = StageOutputs(recording="r", identified=ident, **{
        **_later_stages(), "discrepancy": DiscrepancyStage(
            discrepancy=Discrepancy(0.03, [], 0.004),
            reidentification=Reidentification(effects=("coulomb_friction",), impacts=remeasured))})
    doc = assemble_results(stages)
    top = [i for i in doc.impacts if i.plate == "top"]
    bottom = [i for i in doc.impacts if i.plate == "bottom"]
    assert all(i.cor_method == "coulomb_friction" and math.isclose(i.cor, i.cor_paper - 0.05) for i in top)
    assert all(i.cor_method == PAPER and i.cor == i.cor_paper for i in bottom)
    assert math.isclose(doc.cor_summary.top.mean, np.mean([i.cor_paper for i in top]) - 0.05)
    assert doc.sections["cor_statistics"] == cor_statistics_section(doc.impacts)
    assert doc.sections["cor_statistics"] != cor_statistics_section(ident.impacts)
    assert doc.sections["impacts_model"]["n_reidentified"] == len(top)
    assert doc.complete is True and doc.simulation.deviation("cor_model") == 0.03
    assert doc.sections["ball_spin"] == {"available": True}


def test_sections_and_warnings_keep_one_order_whatever_stages_ran() -> None:
    quiet_simulation = replace(_later_stages()["simulation"], warnings=())
    full = StageOutputs(recording="r", identified=_identified(),
                        completeness=CompletenessStage(section={}, warnings=["lost"], complete=False),
                        consistency=ConsistencyStage(section={"refused": False, "findings": [], "checks": {}},
                                                     warnings=["consistency: fps"]),
                        **{**_later_stages(), "simulation": quiet_simulation})
    doc = assemble_results(full)
    assert list(doc.sections) == ["completeness", "cor_statistics", "regime", "rig_consistency", "consistency",
                                  "impacts_model", "ball_spin"]
    assert doc.warnings == ["lost", "flight 3: 2 frames rejected", "consistency: fps"]
    no_spin = replace(full, ball_spin=BallSpinStage(section=None, why_not="no DicFrame"))
    assert assemble_results(no_spin).warnings[-1] == "ball_spin: not reported: no DicFrame"


def test_the_bag_path_gives_the_direct_paths_document() -> None:
    """The bag path hands the assembler the same stages after a trip through the ROS messages (vibro_ros.convert,
    as the fitter publishes and `vibro results` reads them): the same results.json, number for number, to the
    one rounding of a mm <-> m conversion."""
    convert = pytest.importorskip("vibro_ros.convert")
    pytest.importorskip("vibro_msgs.msg")
    ident = _identified()
    direct = StageOutputs(recording="r", identified=replace(ident, warnings=(), sections={}), **_later_stages())
    carried = Identified(structure=convert.structure_from_message(convert.structure_to_message(ident.structure, 1.0)),
                         flights=[convert.flight_from_message(convert.flight_to_message(f, True))
                                  for f in ident.flights],
                         impacts=[convert.impact_from_message(convert.impact_to_message(i, True))
                                  for i in ident.impacts])
    a = assemble_results(direct).to_dict()
    b = assemble_results(replace(direct, identified=carried)).to_dict()
    _assert_close(a, b, "")
    assert json.dumps(list(a)) == json.dumps(list(b))  # the same sections in the same order


def _assert_close(a, b, path: str) -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), path
        for k in a:
            _assert_close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b)):
            _assert_close(x, y, f"{path}[{k}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert abs(a - b) <= 4.5e-16 * max(1.0, abs(a)), f"{path}: {a!r} vs {b!r}"  # 2 ulp: one mm <-> m rounding
    else:
        assert a == b, f"{path}: {a!r} vs {b!r}"


def test_impacts_measured_with_a_local_structure_velocity_are_named_and_said_by_stretch() -> None:
    ident = _identified()
    # the final model measures every impact 0.01 lower; impacts 4-6 sit where its structure misses the measured
    # one (a drive that changed there): they are measured with the local structure velocity, one stretch
    local = {k: LocalStructure(t_paper_s=i.t_s, cor_global=i.cor - 0.03, cor_shift=0.02,
                               structure_velocity_misfit_mps=2e-3 * (k - 3))
             for k, i in enumerate(ident.impacts) if 4 <= k <= 6}
    remeasured = [replace(i, cor=i.cor - 0.01, t_paper_s=i.t_s) for i in ident.impacts]

    def assembled(kept: list[int]) -> ResultsDocument:
        redo = Reidentification(effects=("coulomb_friction",), impacts=remeasured,
                                local_structure=[local[k] for k in kept])
        return assemble_results(StageOutputs(recording="r", identified=ident, discrepancy=DiscrepancyStage(
            discrepancy=Discrepancy(0.03, [], 0.004), reidentification=redo)))

    doc = assembled([4, 5, 6])
    methods = [i.cor_method for i in doc.impacts]
    assert methods == ["coulomb_friction"] * 4 + ["coulomb_friction+local_structure"] * 3 + ["coulomb_friction"] * 5
    assert all(math.isclose(i.cor, i.cor_paper - 0.01) for i in doc.impacts)  # the re-measured values, all
    section = doc.sections["impacts_model"]
    assert section["n_reidentified"] == N_IMPACTS
    (stretch,) = section["local_structure"]
    assert (stretch["t_start_s"], stretch["t_end_s"], stretch["n_impacts"]) == (ident.impacts[4].t_s,
                                                                                ident.impacts[6].t_s, 3)
    assert math.isclose(stretch["max_cor_shift"], 0.02)
    assert math.isclose(stretch["max_structure_velocity_misfit_mps"], 6e-3)
    assert any(w.startswith("impacts_model: 3 impact(s) measured with the structure velocity of a fit local")
               for w in doc.warnings)
    # two stretches when an impact between them keeps the final model's structure
    assert [s["n_impacts"] for s in assembled([4, 6]).sections["impacts_model"]["local_structure"]] == [1, 1]
    # none: no section key, no warning
    plain = assembled([])
    assert "local_structure" not in plain.sections["impacts_model"]
    assert not any(w.startswith("impacts_model") for w in plain.warnings)
