"""A separate OS process that plays the fitter and the tracker for the discrepancy node:

    python tests/discrepancy_feeder.py case.json [--seconds 60]

case.json holds {"sections": results sections, "track": {column: list}}. Publishes the DIC frames
(latched history QoS, as dic_tracker, once the node listens), the structure fit, the final flights and
impacts, the fitter's end-of-stream statuses and the simulator's "simulation" finished status, then
lingers so that the transient-local results reach late joiners.
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("case")
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    case = json.loads(open(args.case, encoding="utf-8").read())

    import rclpy

    from vibro_msgs.msg import DicFrame, FreeFlight, ImpactEstimate, StreamStatus, StructureMotion
    from vibro_ros import topics
    from vibro_ros.node_support import HISTORY_QOS, RESULTS_QOS

    rclpy.init()
    node = rclpy.create_node("vibro_test_discrepancy_feeder")
    pub_dic = node.create_publisher(DicFrame, topics.DIC.name, HISTORY_QOS)  # as dic_tracker
    pub_s = node.create_publisher(StructureMotion, topics.STRUCTURE.name, RESULTS_QOS)
    pub_f = node.create_publisher(FreeFlight, topics.FLIGHTS.name, RESULTS_QOS)
    pub_i = node.create_publisher(ImpactEstimate, topics.IMPACTS.name, RESULTS_QOS)
    pub_st = node.create_publisher(StreamStatus, topics.STATUS.name, RESULTS_QOS)
    deadline = time.monotonic() + args.seconds
    while pub_dic.get_subscription_count() == 0 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    tr = case["track"]
    for k in range(len(tr["t_s"])):
        pub_dic.publish(DicFrame(frame_index=int(tr["frame"][k]), t_s=float(tr["t_s"][k]),
                                 ball_mm=float(tr["ball_mm"][k]), structure_mm=float(tr["structure_mm"][k]),
                                 ball_valid_points=4, ball_mesh_points=4, structure_valid_points=24,
                                 structure_mesh_points=24, ball_mean_zncc=1.0, structure_mean_zncc=1.0, lost=False))
    pub_st.publish(StreamStatus(stream="dic", items_sent=len(tr["t_s"]), items_lost=0, finished=True))
    sec = case["sections"]
    s = sec["structure"]
    pub_s.publish(StructureMotion(amplitude_mm=s["amplitude_mm"], frequency_hz=s["frequency_hz"],
                                  phase_rad=s["phase_rad"], offset_mm=s["offset_mm"],
                                  dic_bias_json=json.dumps(sec["dic_bias"]) if "dic_bias" in sec else ""))
    for f in sec["flights"]:
        pub_f.publish(FreeFlight(index=f["index"], t_start_s=f["t_first_frame"], t_end_s=f["t_last_frame"],
                                 a_mm_per_s2=f["a"], b_mm_per_s=f["b"], c_mm=f["c"], direction=f["direction"],
                                 friction_n=f["friction_n"] if f["friction_n"] is not None else 0.0,
                                 fitted=bool(f["free"]), final=True))
    for i in sec["impacts"]:
        pub_i.publish(ImpactEstimate(index=i["index"], t_s=i["t"], plate=i["plate"], cor=i["cor"],
                                     cor_std=i["cor_std"], v_ball_before_m_per_s=i["v_ball_before"],
                                     v_ball_after_m_per_s=i["v_ball_after"], v_structure_m_per_s=i["v_structure"],
                                     flight_before=i["flight_before"], flight_after=i["flight_after"], final=True))
    for stream, n in (("flights", len(sec["flights"])), ("impacts", len(sec["impacts"])), ("simulation", 2)):
        pub_st.publish(StreamStatus(stream=stream, items_sent=n, items_lost=0, finished=True))
    print("SENT", flush=True)
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
