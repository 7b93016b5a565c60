"""ROS node ``simulator``: replay the identified run through the COR and Hertz models, publish D.

Collects the fitter's structure motion, final free flights and impact estimates and the
measured ball displacement (vibro/dic); once the fitter's end-of-stream statuses say how
many final flights and impacts there are and they have all arrived, it runs :func:`vibro_sim.measured.replay_and_score` (the same core as
``vibro analyze``) and publishes one SimulationResult per model, then its own
end-of-stream status.
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node

from vibro_io import topics
from vibro_io.errors import RecordingError
from vibro_io.node_support import (RESULTS_QOS, STREAM_QOS, Health, StatusPublisher, declare, run_node,
                                   stamp_from_seconds)
from vibro_io.rig import load_rig
from vibro_msgs.msg import DicFrame, FreeFlight, ImpactEstimate, SimulationResult, StreamStatus, StructureMotion

from .measured import FlightSummary, ImpactSummary, StructureSine, replay_and_score, replay_inputs
from .params import BallCavity

MODELS = ("cor_model", "hertz_model")


class Simulator(Node):
    def __init__(self) -> None:
        super().__init__("simulator")
        rig_file = declare(self, "rig_file", "", "rig.yaml of the recording (ball, gap, materials)")
        models = list(declare(self, "models", list(MODELS), "models to run: cor_model, hertz_model"))
        self.max_points = int(declare(self, "max_points", 5000, "at most this many samples per published trajectory"))
        if not rig_file:
            raise RecordingError("simulator: parameter 'rig_file' is required")
        bad = [m for m in models if m not in MODELS]
        if bad:
            raise RecordingError(f"simulator: parameter 'models' has unknown entries {bad} (known: {MODELS})")
        self.models = models
        self.rig = load_rig(rig_file)
        self.cavity = BallCavity.from_rig(self.rig)
        self.structure: StructureMotion | None = None
        self.flights: dict[int, FreeFlight] = {}
        self.impacts: dict[int, ImpactEstimate] = {}
        self.ball: dict[int, tuple[float, float]] = {}
        self.ran = False
        self.announced: dict[str, int] = {}
        self.health = Health(self)
        self.status = StatusPublisher(self, "simulation")
        self.pub = self.create_publisher(SimulationResult, topics.SIMULATION.name, RESULTS_QOS)
        self.create_subscription(StructureMotion, topics.STRUCTURE.name, self._on_structure, RESULTS_QOS)
        self.create_subscription(FreeFlight, topics.FLIGHTS.name, self._on_flight, RESULTS_QOS)
        self.create_subscription(ImpactEstimate, topics.IMPACTS.name, self._on_impact, RESULTS_QOS)
        self.create_subscription(DicFrame, topics.DIC.name, self._on_dic, STREAM_QOS)
        self.create_subscription(StreamStatus, topics.STATUS.name, self._on_status, RESULTS_QOS)

    def _on_structure(self, msg: StructureMotion) -> None:
        self.structure = msg
        self._maybe_run()

    def _on_flight(self, msg: FreeFlight) -> None:
        if msg.final:  # streamed flights are previews; the final fit is what gets simulated
            self.flights[msg.index] = msg
            self._maybe_run()

    def _on_impact(self, msg: ImpactEstimate) -> None:
        if msg.final:
            self.impacts[msg.index] = msg
            self._maybe_run()

    def _on_dic(self, msg: DicFrame) -> None:
        if not msg.lost:
            self.ball[int(msg.frame_index)] = (msg.t_s, msg.ball_mm)

    def _on_status(self, msg: StreamStatus) -> None:
        if msg.stream in ("impacts", "flights") and msg.finished:
            self.announced[msg.stream] = int(msg.items_sent)
            self._maybe_run()

    def _maybe_run(self) -> None:
        """Simulate once every final flight and impact the fitter announced has arrived (any order)."""
        if self.ran or len(self.announced) < 2:
            return
        if len(self.impacts) < self.announced["impacts"] or len(self.flights) < self.announced["flights"]:
            return
        if self.structure is None and self.announced["impacts"] > 0:
            return
        self.ran = True
        self.simulate()

    def simulate(self) -> None:
        s = self.structure
        if s is None or not self.impacts or not self.ball:
            self.health.warn("nothing to simulate (no structure fit, impacts or DIC data received)")
            self.get_logger().warning("nothing to simulate: no structure fit, impact or DIC frame received")
            self.status.publish(0, 0, True)
            return
        sine = StructureSine(s.amplitude_mm, s.frequency_hz, s.phase_rad, s.offset_mm)
        flights = [FlightSummary(f.t_start_s, f.t_end_s, f.a_mm_per_s2, f.b_mm_per_s, f.c_mm, f.friction_n, f.fitted)
                   for _, f in sorted(self.flights.items())]
        impacts = [ImpactSummary(i.t_s, i.plate, i.cor) for _, i in sorted(self.impacts.items())]
        rows = np.array([self.ball[k] for k in sorted(self.ball)])
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
            msg = SimulationResult(model=model, deviation=score["deviation"], impacts=score["impacts"])
            msg.t_s = score["t_s"][::step].tolist()
            msg.ball_mm = score["ball_mm"][::step].tolist()
            msg.measured_ball_mm = score["measured_mm"][::step].tolist()
            stamp_from_seconds(msg.header, float(score["t_s"][-1]))
            self.pub.publish(msg)
            sent += 1
            self.get_logger().info(f"{model}: D = {100 * score['deviation']:.2f} %")
        self.status.publish(sent, len(self.models) - sent, True)


def main(args: list[str] | None = None) -> int:
    return run_node(Simulator, args)


if __name__ == "__main__":
    sys.exit(main())
