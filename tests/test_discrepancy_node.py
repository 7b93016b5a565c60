"""The ``discrepancy`` node over DDS, in separate processes: fitter/tracker messages in (a feeder
process), DiscrepancyFinding messages and the "discrepancy" status out (ros_echo processes)."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
from pathlib import Path

from discrepancy_cases import make_case
from vibro_io.rig import write_rig
from vibro_sim.discrepancy.from_messages import document_from_messages

HERE = Path(__file__).resolve().parent


def _start(*argv: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


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


def test_node_publishes_findings_over_dds(tmp_path: Path, ros_domain: str, udp_only: None):
    sections, track, rig, _ = make_case({"coulomb_friction": {"force_n": 1.5e-4}}, seed=62, frames=300)
    write_rig(rig, tmp_path / "rig.yaml")
    cols = ("frame", "t_s", "ball_mm", "structure_mm")
    case = {"sections": {k: sections[k] for k in ("structure", "flights", "impacts")},
            "track": {c: getattr(track, c).tolist() for c in cols}}
    (tmp_path / "case.json").write_text(json.dumps(case))
    echo = _start(str(HERE / "ros_echo.py"), "vibro_msgs/msg/DiscrepancyFinding", "vibro/discrepancy",
                  "--count", "1", "--seconds", "90", "--qos", "results")
    node = _start("-m", "vibro_sim.discrepancy_node", "--ros-args", "-p", f"rig_file:={tmp_path / 'rig.yaml'}")
    feeder = None
    try:
        assert echo.stdout.readline().strip() == "READY"
        feeder = _start(str(HERE / "discrepancy_feeder.py"), str(tmp_path / "case.json"), "--seconds", "60")
        out, _ = echo.communicate(timeout=120)
    finally:
        node.send_signal(signal.SIGINT)
        _, node_err = node.communicate(timeout=20)
        feeder_err = ""
        if feeder is not None:
            feeder.kill()
            feeder_err = feeder.communicate()[1]
        echo.kill()
    rows = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    assert len(rows) == 1, f"node:\n{node_err}\nfeeder:\n{feeder_err}"
    f = rows[0]
    assert f["effect"] == "coulomb_friction" and f["parameter_names"] == ["force_n"]
    # same bound as the engine tests: 5 sigma of the reported std plus 1 %
    assert abs(f["parameter_values"][0] - 1.5e-4) <= 5 * f["parameter_std"][0] + 1.5e-6
    assert f["deviation_after"] < f["deviation_before"] and "flights" in f["where"]
    assert all(math.isfinite(v) for v in f["parameter_std"])
    assert node.returncode == 0 and "Traceback" not in node_err
