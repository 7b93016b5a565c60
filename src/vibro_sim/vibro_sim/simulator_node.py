"""ROS node ``simulator``: replay the identified run through the COR and Hertz models, publish D.

Collects the fitter's structure motion, final free flights and impact estimates and the
measured ball displacement (vibro/dic) with :class:`vibro_ros.fit_results.FinalFitResults`;
once everything the fitter and the tracker announced has arrived, it runs :func:`vibro_sim.measured.replay_and_score` (the same core as
``vibro analyze``) and publishes one SimulationResult per model, then its own
end-of-stream status.
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node

from vibro_ros import topics
from vibro_io.errors import RecordingError
from vibro_ros.fit_results import FinalFitResults
from vibro_model.results import SimulationRun
from vibro_model.units import mm_to_m
from vibro_ros.convert import simulation_run_to_message
from vibro_ros.node_support import RESULTS_QOS, Health, StatusPublisher, declare, run_node, time_origin_parameter
from vibro_ros.readiness import ReaderGate
from vibro_io.rig import load_rig
from vibro_msgs.msg import SimulationResult

from .measured import FlightSummary, ImpactSummary, StructureSine, replay_and_score, replay_inputs
from .params import BallCavity

MODELS = ("cor_model", "hertz_model")


class Simulator(Node):
    def __init__(self) -> None:
        super().__init__("simulator")
        rig_file = declare(self, "rig_file", "", "rig.yaml of the recording (ball, gap, materials)")
        models = list(declare(self, "models", list(MODELS), "models to run: cor_model, hertz_model"))
        self.max_points = int(declare(self, "max_points", 5000, "at most this many samples per published trajectory"))
        dic_wait_s = float(declare(self, "dic_wait_s", 5.0,
                                   "without the tracker's 'dic' end-of-stream status, run once no DIC frame "
                                   "has arrived for this long (s)"))
        if not rig_file:
            raise RecordingError("simulator: parameter 'rig_file' is required")
        bad = [m for m in models if m not in MODELS]
        if bad:
            raise RecordingError(f"simulator: parameter 'models' has unknown entries {bad} (known: {MODELS})")
        self.models = models
        self.rig = load_rig(rig_file)
        self.time_origin_ns = time_origin_parameter(self)
        self.cavity = BallCavity.from_rig(self.rig)
        self.ran = False
        self.health = Health(self)
        self.status = StatusPublisher(self, "simulation")
        self.pub = self.create_publisher(SimulationResult, topics.SIMULATION.name, RESULTS_QOS)
        self.results = FinalFitResults(self, self._maybe_run, dic_wait_s)
        self.gate = ReaderGate(self, health=self.health)  # exits once its readers have the final outputs
        self.done = self.gate.done

    def _maybe_run(self) -> None:
        """Simulate once, when the fitter's final results and the DIC frames are complete (any order)."""
        if not self.ran and self.results.complete():
            self.ran = True
            self.simulate()
            self.gate.finish()

    def simulate(self) -> None:
        s = self.results.structure
        tracked = self.results.tracked_frames()
        if s is None or not self.results.impacts or not tracked:
            self.health.warn("nothing to simulate (no structure fit, impacts or DIC data received)")
            self.get_logger().warning("nothing to simulate: no structure fit, impact or DIC frame received")
            self.status.publish(0, 0, True)
            return
        sine = StructureSine(s.amplitude_mm, s.frequency_hz, s.phase_rad, s.offset_mm)
        flights = [FlightSummary(f.t_start_s, f.t_end_s, f.a_mm_per_s2, f.b_mm_per_s, f.c_mm, f.friction_n, f.fitted)
                   for f in self.results.sorted_flights()]
        impacts = [ImpactSummary(i.t_s, i.plate, i.cor) for i in self.results.sorted_impacts()]
        rows = np.array([(m.t_s, m.ball_mm) for m in tracked])
        try:
            inputs = replay_inputs(sine, flights, impacts, s.ball_offset_mm, self.rig.free_play_mm,
                                   float(rows[-1, 0]))
        except ValueError as exc:
            self.health.warn(str(exc))
            self.get_logger().warning(f"cannot simulate: {exc}")
            self.status.publish(0, 0, True)
            return
        scores = replay_and_score(inputs, self.cavity, rows[:, 0], rows[:, 1], s.ball_offset_mm, self.models)
        sent = 0
        for model, score in scores.items():
            if "error" in score:
                self.health.warn(f"{model}: {score['error']}")
                self.get_logger().error(f"{model} failed: {score['error']}")
                continue
            step = max(1, int(np.ceil(score["t_s"].size / self.max_points)))
            run = SimulationRun(model, float(score["deviation"]), int(score["impacts"]), score["t_s"][::step],
                                mm_to_m(score["ball_mm"][::step]), mm_to_m(score["measured_mm"][::step]))
            msg = simulation_run_to_message(run, float(score["t_s"][-1]), self.time_origin_ns)
            self.pub.publish(msg)
            sent += 1
            self.get_logger().info(f"{model}: D = {100 * score['deviation']:.2f} %")
        self.status.publish(sent, len(self.models) - sent, True)


def main(args: list[str] | None = None) -> int:
    return run_node(Simulator, args)


if __name__ == "__main__":
    sys.exit(main())
