"""The ``discrepancy`` node over DDS, in separate processes: fitter/tracker messages in (a feeder
process), DiscrepancyFinding messages and the "discrepancy" status out (ros_echo processes)."""

from __future__ import annotations

import math
from pathlib import Path

from discrepancy_cases import make_case
from discrepancy_dds import feed_case, run_discrepancy_node

from vibro_discrepancy.from_messages import document_from_messages
from vibro_io.rig import write_rig


def test_document_from_messages_roundtrip():
    # the node rebuilds the results document from messages; the analysis must see the same flights/impacts
    from vibro_msgs.msg import FreeFlight, ImpactEstimate, StructureMotion

    sections, _, _, _ = make_case({}, seed=61, frames=200)
    st = sections["structure"]
    s = StructureMotion(amplitude_mm=st["amplitude_mm"], frequency_hz=st["frequency_hz"], phase_rad=st["phase_rad"],
                        offset_mm=st["offset_mm"], rms_residual_mm=st["rms_residual_mm"])
    flights = [FreeFlight(index=f["index"], t_start_s=f["t_first_frame"], t_end_s=f["t_last_frame"], a_mm_per_s2=f["a"],
                          b_mm_per_s=f["b"], c_mm=f["c"], direction=f["direction"], friction_n=f["friction_n"] or 0.0,
                          fitted=f["free"]) for f in sections["flights"]]
    impacts = [ImpactEstimate(index=i["index"], t_s=i["t"], plate=i["plate"], cor=i["cor"], cor_std=i["cor_std"],
                              v_ball_before_m_per_s=i["v_ball_before"], v_ball_after_m_per_s=i["v_ball_after"],
                              v_structure_m_per_s=i["v_structure"], flight_before=i["flight_before"],
                              flight_after=i["flight_after"]) for i in sections["impacts"]]
    back = document_from_messages(s, flights, impacts)
    for a, b in zip(back.flights, sections["flights"]):
        assert a.t_start_s == b["t_start"] and a.t_end_s == b["t_end"] and a.free == b["free"]
    assert [i.t_s for i in back.impacts] == [i["t"] for i in sections["impacts"]]


def test_node_publishes_findings_over_dds(tmp_path: Path, ros_domain: str):
    sections, track, rig, _ = make_case({"coulomb_friction": {"force_n": 1.5e-4}}, seed=62, frames=300)
    write_rig(rig, tmp_path / "rig.yaml")
    run = run_discrepancy_node(feed_case(tmp_path / "case.json", sections, track), tmp_path / "rig.yaml",
                               "vibro_msgs/msg/DiscrepancyFinding", "vibro/discrepancy", count=1)
    rows = run.rows
    assert len(rows) == 1, run.logs
    f = rows[0]
    assert f["effect"] == "coulomb_friction" and f["parameter_names"] == ["force_n"]
    # same bound as the engine tests: 5 sigma of the reported std plus 1 %
    assert abs(f["parameter_values"][0] - 1.5e-4) <= 5 * f["parameter_std"][0] + 1.5e-6
    assert f["deviation_after"] < f["deviation_before"] and "flights" in f["where"]
    assert all(math.isfinite(v) for v in f["parameter_std"])
    assert run.node_returncode == 0 and "Traceback" not in run.node_err
