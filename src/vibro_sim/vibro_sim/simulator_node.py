"""ROS node ``simulator``: replay the identified run through the COR and Hertz models, publish D.

Collects the fitter's structure motion, final free flights and impact estimates and the
measured ball displacement (vibro/dic) with :class:`vibro_ros.fit_results.FinalFitResults`;
once everything the fitter and the tracker announced has arrived, it converts them to the domain model
(:mod:`vibro_ros.convert`) and runs :func:`vibro_sim.measured.replay_and_score` (the same core as
``vibro analyze``) and publishes one SimulationResult per model, then its own
end-of-stream status.
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node

from vibro_io.dic_bias import ball_as_identified
from vibro_io.rig import load_rig
from vibro_model.codec import nan_if_none
from vibro_model.drive_envelope import DriveEnvelope
from vibro_model.errors import RecordingError
from vibro_model.units import mm_to_m
from vibro_msgs.msg import SimulationResult
from vibro_ros import topics
from vibro_ros.convert import (
    dic_bias_from_message,
    drive_from_message,
    flight_from_message,
    impact_from_message,
    simulation_run_to_message,
    structure_from_message,
)
from vibro_ros.fit_results import FinalFitResults
from vibro_ros.node_support import RESULTS_QOS, Health, StatusPublisher, declare, run_node, time_origin_parameter
from vibro_ros.readiness import ReaderGate

from .measured import decimated, replay_and_score, replay_inputs
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
        r = self.results
        if r.incomplete_words():  # D over part of the run is no model's deviation: not computed
            self.health.warn(r.incomplete_words())
            self.get_logger().warning(r.incomplete_words())
            self.status.publish(0, 0, True)
            return
        tracked = r.tracked_frames()
        if r.structure is None or not r.impacts or not tracked:
            self.health.warn("nothing to simulate (no structure fit, impacts or DIC data received)")
            self.get_logger().warning("nothing to simulate: no structure fit, impact or DIC frame received")
            self.status.publish(0, 0, True)
            return
        structure = structure_from_message(r.structure)
        t_s = np.array([m.t_s for m in tracked], dtype=float)
        offset_m = nan_if_none(structure.ball_offset_m)
        try:
            # the ball as the fitter identified it: its sub-pixel bias taken out (vibro analyze's replay reads it so)
            ball_m = mm_to_m(ball_as_identified([m.ball_mm for m in tracked], dic_bias_from_message(r.structure)))
            envelope = DriveEnvelope.of_drive_section(drive_from_message(r.structure), structure.offset_m or 0.0)
            inputs = replay_inputs(structure, [flight_from_message(f) for f in r.sorted_flights()],
                                   [impact_from_message(i) for i in r.sorted_impacts()], mm_to_m(self.rig.free_play_mm),
                                   float(t_s[-1]), offset_m, envelope)
        except (ValueError, RecordingError) as exc:
            self.health.warn(str(exc))
            self.get_logger().warning(f"cannot simulate: {exc}")
            self.status.publish(0, 0, True)
            return
        runs, errors = replay_and_score(inputs, self.cavity, t_s, ball_m, offset_m, self.models)
        for model, error in errors.items():
            self.health.warn(f"{model}: {error}")
            self.get_logger().error(f"{model} failed: {error}")
        for run in runs.values():
            msg = simulation_run_to_message(decimated(run, self.max_points), float(run.t_s[-1]), self.time_origin_ns)
            self.pub.publish(msg)
            self.get_logger().info(f"{run.model}: D = {100 * run.deviation:.2f} %")
        self.status.publish(len(runs), len(self.models) - len(runs), True)


def main(args: list[str] | None = None) -> int:
    return run_node(Simulator, args)


if __name__ == "__main__":
    sys.exit(main())
