"""ROS node ``discrepancy``: the discrepancy analysis of a run, published as DiscrepancyFinding messages.

Collects what the fitter published (structure motion, final free flights and impacts) and the DIC
frames; when the simulator reports its stream "simulation" finished, every final flight and impact
the fitter announced has arrived and the tracker's DIC frames are complete (its "dic" status, or no
new frame for ``dic_wait_s``), it runs :func:`vibro_discrepancy.run_discrepancy` on the
results document of those messages (domain-model types, :mod:`vibro_ros.convert`; the same core as
``vibro analyze``); when a finding changes how an impact is measured (harmonics, a flight force)
it publishes the impacts measured again under the final model (:mod:`vibro_discrepancy.reidentify`,
applied by the results assembler, :mod:`vibro_model.assemble`, as for ``vibro analyze``) on
vibro/impacts_final_model (ImpactEstimate, final) with the status of stream "impacts_final_model"; then one
DiscrepancyFinding per finding and its own status (stream "discrepancy", finished). No finding:
only the statuses (items_sent = 0).
"""

from __future__ import annotations

import json
import sys
from dataclasses import asdict, replace

from rclpy.node import Node

from vibro_discrepancy import run_discrepancy
from vibro_discrepancy.from_messages import stages_from_messages, track_from_messages
from vibro_discrepancy.reidentify import reidentification
from vibro_io.dic_bias import track_as_identified
from vibro_io.rig import load_rig
from vibro_model.assemble import PAPER, DiscrepancyStage, assemble_results
from vibro_model.errors import RecordingError
from vibro_msgs.msg import DiscrepancyFinding, ImpactEstimate
from vibro_ros import topics
from vibro_ros.convert import finding_to_message, impact_to_message
from vibro_ros.exit_codes import INCOMPLETE
from vibro_ros.fit_results import FinalFitResults
from vibro_ros.node_support import RESULTS_QOS, Health, StatusPublisher, declare, run_node, time_origin_parameter
from vibro_ros.readiness import ReaderGate

#: the stream (vibro/status) of the re-measured impacts on vibro/impacts_final_model
FINAL_MODEL_STREAM = "impacts_final_model"


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
        self.time_origin_ns = time_origin_parameter(self)
        self.ran = False
        self.health = Health(self)
        self.status = StatusPublisher(self, "discrepancy")
        self.pub = self.create_publisher(DiscrepancyFinding, topics.DISCREPANCY.name, RESULTS_QOS)
        self.final_model_status = StatusPublisher(self, FINAL_MODEL_STREAM)
        self.pub_impacts = self.create_publisher(ImpactEstimate, topics.IMPACTS_FINAL_MODEL.name, RESULTS_QOS)
        self.results = FinalFitResults(self, self._maybe_run, self.dic_wait_s)
        self.gate = ReaderGate(self, health=self.health)  # exits once its readers have the final outputs
        self.done = self.gate.done

    def _maybe_run(self) -> None:
        if self.ran or (self.wait_for_simulation and "simulation" not in self.results.finished):
            return
        if self.results.complete():
            self.ran = True
            self.analyse()
            self.gate.finish()

    def analyse(self) -> None:
        r = self.results
        incomplete = r.incomplete_words()
        if incomplete:  # judged on part of the run, a "no finding" would be a claim about frames never seen
            self.health.warn(incomplete)
            self.get_logger().error(incomplete)
            self.final_model_status.publish(0, 0, True)
            self.status.publish(0, 0, True)
            self.exit_code = INCOMPLETE
            return
        if r.structure is None or not r.frames or not r.flights:
            self.health.warn("nothing to analyse (no structure fit, flights or DIC frames received)")
            self.get_logger().warning("nothing to analyse: no structure fit, flight or DIC frame received")
            self.final_model_status.publish(0, 0, True)
            self.status.publish(0, 0, True)
            return
        try:
            stages = stages_from_messages(r.structure, r.flights.values(), r.impacts.values())
            # the DIC frames as the fitter identified them: its sub-pixel bias taken out (vibro analyze's track)
            track = track_as_identified(track_from_messages(r.frames.values()),
                                        stages.identified.sections.get("dic_bias"))
            run = run_discrepancy(assemble_results(stages), track, self.rig)
        except RecordingError as exc:
            self.health.warn(str(exc))
            self.get_logger().warning(f"discrepancy analysis not possible: {exc}")
            self.final_model_status.publish(0, 0, True)
            self.status.publish(0, 0, True)
            return
        t_last = max(float(m.t_s) for m in r.frames.values())
        block = run.result
        redo = reidentification(block.findings, run)
        self.health.values[topics.LOCAL_STRUCTURE_KEY] = json.dumps([asdict(k) for k in redo.local_structure])
        self.health.values[topics.FRICTION_CORRECTION_KEY] = json.dumps(asdict(redo.friction)) if redo.friction else ""
        self.health.values[topics.DISCREPANCY_KEY] = json.dumps(block.to_dict())
        self.health.publish()
        final = assemble_results(replace(stages, discrepancy=DiscrepancyStage(discrepancy=block,
                                                                              reidentification=redo)))
        remeasured = [i for i in final.impacts if i.cor_method != PAPER]
        for imp in remeasured:
            self.pub_impacts.publish(impact_to_message(imp, final=True, origin_ns=self.time_origin_ns))
        if remeasured:
            self.get_logger().info(f"{len(remeasured)} impacts measured again under the final model "
                                   f"({remeasured[0].cor_method})")
        self.final_model_status.publish(len(remeasured), 0, True)
        for k, finding in enumerate(block.findings):
            msg = finding_to_message(finding, k, t_last, self.time_origin_ns)
            self.pub.publish(msg)
            self.get_logger().info(f"finding {k}: {msg.effect} {dict(zip(msg.parameter_names, msg.parameter_values))}"
                                   f"; D {msg.deviation_before:.4g} -> {msg.deviation_after:.4g}")
        if not block.findings:
            self.get_logger().info(f"no finding: the baseline explains the run (D = {block.baseline_deviation})")
        self.status.publish(len(block.findings), 0, True)


def main(args: list[str] | None = None) -> int:
    return run_node(Discrepancy, args)


if __name__ == "__main__":
    sys.exit(main())
