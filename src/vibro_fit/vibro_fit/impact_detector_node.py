"""ROS node ``impact_detector``: AccelBlock messages in, one AccelImpact per detected impact out.

A thin adapter over :class:`vibro_fit.accel_impacts.AccelImpactDetector` (the rule of
``vibro analyze``): zero-phase high-pass, threshold median + k_sigma x robust noise,
refractory time, plate by channel energy, clipping flag. A gap in the block numbering
is reported (log, diagnostics), never silently bridged. vibro/accel is a latched history, so a detector
restarted mid-run detects from block 0 again; blocks of another publisher or run, repeated or going
back, or a history that does not begin at block 0, stop the node (vibro_ros.guard).
"""

from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node

from vibro_io.rig import load_rig
from vibro_model.errors import RecordingError
from vibro_msgs.msg import AccelBlock, AccelImpact, StreamStatus
from vibro_ros import topics
from vibro_ros.adaptive_qos import results_subscription
from vibro_ros.guard import InputGuard
from vibro_ros.node_support import (
    RESULTS_QOS,
    Health,
    StatusPublisher,
    declare,
    history_depth_parameter,
    history_qos,
    run_node,
    stamp_from_seconds,
    time_origin_parameter,
)
from vibro_ros.readiness import ReaderGate

from .accel_impacts import AccelImpact as Impact
from .accel_impacts import AccelImpactDetector


def impact_message(index: int, impact: Impact, origin_ns: int = 0) -> AccelImpact:
    """The AccelImpact of ``impact``: ``t_s`` DAQ time, the header stamped with it on the lab clock of ``origin_ns``."""
    msg = AccelImpact(index=index, t_s=impact.t_s, plate=impact.plate, peak_ms2=impact.peak_ms2,
                      upper_energy_m2s3=impact.energy_upper, lower_energy_m2s3=impact.energy_lower,
                      clipped=impact.clipped)
    msg.dominant_frequencies_hz = [float(f) for f in impact.dominant_frequencies_hz]
    msg.header.frame_id = "daq"
    stamp_from_seconds(msg.header, impact.t_s, origin_ns)
    return msg


class ImpactDetector(Node):
    def __init__(self) -> None:
        super().__init__("impact_detector")
        rig_file = declare(self, "rig_file", "", "rig.yaml (nominal excitation frequency)")
        self.highpass_hz = float(declare(self, "highpass_hz", 100.0, "zero-phase high-pass cut-off (Hz)"))
        self.k_sigma = float(declare(self, "k_sigma", 8.0, "threshold in robust noise units above the median"))
        if not rig_file:
            raise RecordingError("impact_detector: parameter 'rig_file' is required")
        if self.highpass_hz <= 0 or self.k_sigma <= 0:
            raise RecordingError("impact_detector: 'highpass_hz' and 'k_sigma' must be > 0")
        self.frequency_hz = load_rig(rig_file).excitation.frequency_hz
        self.time_origin_ns = time_origin_parameter(self)
        self.detector: AccelImpactDetector | None = None
        self.next_block = 0
        self.sent = 0
        self.gaps = 0
        self.finished = False
        self.blocks_announced: int | None = None
        self.health = Health(self)
        self.health.rate_counter = "blocks"
        self.status = StatusPublisher(self, "accel_impacts")
        self.pub = self.create_publisher(AccelImpact, topics.ACCEL_IMPACTS.name, RESULTS_QOS)
        self.guard = InputGuard(self)
        self.guard.watch(topics.ACCEL)
        results_subscription(self, AccelBlock, topics.ACCEL.name, self._on_block,
                             history_qos(history_depth_parameter(self)))
        results_subscription(self, StreamStatus, topics.STATUS.name, self._on_status)
        self.gate = ReaderGate(self, health=self.health)  # exits once its readers have the final outputs
        self.done = self.gate.done

    def _publish(self, impacts: list[Impact]) -> None:
        for impact in impacts:
            self.pub.publish(impact_message(self.sent, impact, self.time_origin_ns))
            self.sent += 1
            if impact.clipped:
                self.health.warn(f"impact at {impact.t_s:.5f} s clipped on the {impact.plate} plate's sensor")

    def _on_block(self, msg: AccelBlock) -> None:
        if not self.guard.accept(topics.ACCEL.name, run_id=msg.run_id, index=msg.block_index, first_index=0,
                                 what="block"):
            return
        if msg.block_index != self.next_block:
            self.gaps += 1
            self.health.count("block_gaps")
            self.health.warn(f"accelerometer blocks {self.next_block}..{msg.block_index - 1} missing")
            self.get_logger().warning(f"accelerometer blocks {self.next_block}..{msg.block_index - 1} missing")
        self.next_block = msg.block_index + 1
        if self.detector is None:
            self.detector = AccelImpactDetector(msg.sample_rate_hz, self.frequency_hz,
                                                highpass_hz=self.highpass_hz, k_sigma=self.k_sigma)
        n = len(msg.upper_ms2)
        t = msg.t_start_s + np.arange(n) / msg.sample_rate_hz
        self._publish(self.detector.push_block(t, msg.upper_ms2, msg.lower_ms2))
        self.health.count("blocks")
        self.health.observe(msg.t_start_s + n / msg.sample_rate_hz)
        self._maybe_finish()

    def _on_status(self, msg: StreamStatus) -> None:
        if not self.guard.accept(topics.STATUS.name, run_id=msg.run_id):
            return
        if msg.stream == "accel" and msg.finished:
            self.blocks_announced = int(msg.items_sent)
            self._maybe_finish()

    def _maybe_finish(self) -> None:
        if self.blocks_announced is not None and self.next_block >= self.blocks_announced and not self.finished:
            self.finished = True
            if self.detector is not None:
                self._publish(self.detector.finish())
            self.status.publish(self.sent, self.gaps, True)
            self.get_logger().info(f"done: {self.sent} impacts from {self.next_block} blocks")
            self.gate.finish()


def main(args: list[str] | None = None) -> int:
    return run_node(ImpactDetector, args)


if __name__ == "__main__":
    sys.exit(main())
