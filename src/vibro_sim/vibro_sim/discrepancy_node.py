"""ROS node ``discrepancy``: the discrepancy analysis of a run, published as DiscrepancyFinding messages.

Collects what the fitter published (structure motion, final free flights and impacts) and the DIC
frames; when the simulator reports its stream "simulation" finished, every final flight and impact
the fitter announced has arrived and the tracker's DIC frames are complete (its "dic" status, or no
new frame for ``dic_wait_s``), it runs :func:`vibro_sim.discrepancy.analyse_discrepancy` (the same
core as ``vibro analyze``) and publishes one DiscrepancyFinding per finding, then its own status
(stream "discrepancy", finished). No finding: only the status (items_sent = 0).
"""

from __future__ import annotations

import sys
import time

from rclpy.node import Node

from vibro_io import topics
from vibro_io.errors import RecordingError
from vibro_io.node_support import RESULTS_QOS, STREAM_QOS, Health, StatusPublisher, declare, run_node, \
    stamp_from_seconds
from vibro_io.rig import load_rig
from vibro_msgs.msg import DicFrame, DiscrepancyFinding, FreeFlight, ImpactEstimate, StreamStatus, StructureMotion

from .discrepancy import analyse_discrepancy
from .discrepancy.from_messages import sections_from_messages, track_from_messages


def finding_message(index: int, f: dict) -> DiscrepancyFinding:
    """One finding of the discrepancy block as a message (NaN for missing numbers)."""
    nan = float("nan")
    params = f.get("parameters") or {}
    stds = f.get("parameters_std") or {}
    msg = DiscrepancyFinding(index=index, effect=str(f.get("effect", "")), where=str(f.get("where", "")))
    msg.parameter_names = list(params)
    msg.parameter_values = [float(v) if v is not None else nan for v in params.values()]
    msg.parameter_std = [float(stds[k]) if stds.get(k) is not None else nan for k in params]
    msg.deviation_before = float(f["deviation_before"]) if f.get("deviation_before") is not None else nan
    msg.deviation_after = float(f["deviation_after"]) if f.get("deviation_after") is not None else nan
    return msg


class Discrepancy(Node):
    def __init__(self) -> None:
        super().__init__("discrepancy")
        rig_file = declare(self, "rig_file", "", "rig.yaml of the recording (ball mass, free play)")
        self.wait_for_simulation = bool(declare(self, "wait_for_simulation", True,
                                                "run after the simulator's 'simulation' status is finished "
                                                "(false: as soon as the fitter's results are complete)"))
        self.dic_wait_s = float(declare(self, "dic_wait_s", 5.0,
                                        "without the tracker's 'dic' end-of-stream status, run once no DIC frame "
                                        "has arrived for this long (s)"))
        if not rig_file:
            raise RecordingError("discrepancy: parameter 'rig_file' is required")
        self.rig = load_rig(rig_file)
        self.structure: StructureMotion | None = None
        self.flights: dict[int, FreeFlight] = {}
        self.impacts: dict[int, ImpactEstimate] = {}
        self.frames: dict[int, DicFrame] = {}
        self.announced: dict[str, int] = {}
        self.simulation_done = False
        self.last_dic = time.monotonic()
        self.ran = False
        self.health = Health(self)
        self.status = StatusPublisher(self, "discrepancy")
        self.pub = self.create_publisher(DiscrepancyFinding, topics.DISCREPANCY.name, RESULTS_QOS)
        self.create_subscription(StructureMotion, topics.STRUCTURE.name, self._on_structure, RESULTS_QOS)
        self.create_subscription(FreeFlight, topics.FLIGHTS.name, self._on_flight, RESULTS_QOS)
        self.create_subscription(ImpactEstimate, topics.IMPACTS.name, self._on_impact, RESULTS_QOS)
        self.create_subscription(DicFrame, topics.DIC.name, self._on_dic, STREAM_QOS)
        self.create_subscription(StreamStatus, topics.STATUS.name, self._on_status, RESULTS_QOS)
        self.create_timer(0.5, self._maybe_run)

    def _on_structure(self, msg: StructureMotion) -> None:
        self.structure = msg
        self._maybe_run()

    def _on_flight(self, msg: FreeFlight) -> None:
        if msg.final:
            self.flights[msg.index] = msg
            self._maybe_run()

    def _on_impact(self, msg: ImpactEstimate) -> None:
        if msg.final:
            self.impacts[msg.index] = msg
            self._maybe_run()

    def _on_dic(self, msg: DicFrame) -> None:
        self.frames[int(msg.frame_index)] = msg
        self.last_dic = time.monotonic()
        self._maybe_run()

    def _on_status(self, msg: StreamStatus) -> None:
        if msg.stream in ("impacts", "flights", "dic") and msg.finished:
            self.announced[msg.stream] = int(msg.items_sent)
        if msg.stream == "simulation" and msg.finished:
            self.simulation_done = True
        self._maybe_run()

    def _maybe_run(self) -> None:
        if self.ran or "impacts" not in self.announced or "flights" not in self.announced:
            return
        if self.wait_for_simulation and not self.simulation_done:
            return
        if "dic" in self.announced:
            if len(self.frames) < self.announced["dic"]:
                return
        elif time.monotonic() - self.last_dic < self.dic_wait_s:
            return
        if len(self.impacts) < self.announced["impacts"] or len(self.flights) < self.announced["flights"]:
            return
        if self.structure is None and self.announced["impacts"] > 0:
            return
        self.ran = True
        self.analyse()

    def analyse(self) -> None:
        if self.structure is None or not self.frames or not self.flights:
            self.health.warn("nothing to analyse (no structure fit, flights or DIC frames received)")
            self.get_logger().warning("nothing to analyse: no structure fit, flight or DIC frame received")
            self.status.publish(0, 0, True)
            return
        try:
            sections = sections_from_messages(self.structure, self.flights.values(), self.impacts.values())
            doc = analyse_discrepancy(sections, track_from_messages(self.frames.values()), self.rig)
        except RecordingError as exc:
            self.health.warn(str(exc))
            self.get_logger().warning(f"discrepancy analysis not possible: {exc}")
            self.status.publish(0, 0, True)
            return
        t_last = max(float(m.t_s) for m in self.frames.values())
        for k, f in enumerate(doc["findings"]):
            msg = finding_message(k, f)
            stamp_from_seconds(msg.header, t_last)
            self.pub.publish(msg)
            self.get_logger().info(f"finding {k}: {msg.effect} {dict(zip(msg.parameter_names, msg.parameter_values))}"
                                   f"; D {msg.deviation_before:.4g} -> {msg.deviation_after:.4g}")
        if not doc["findings"]:
            self.get_logger().info(f"no finding: the baseline explains the run (D = {doc['baseline_deviation']})")
        self.status.publish(len(doc["findings"]), 0, True)


def main(args: list[str] | None = None) -> int:
    return run_node(Discrepancy, args)


if __name__ == "__main__":
    sys.exit(main())
