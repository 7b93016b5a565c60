"""ROS node ``impact_detector``: AccelBlock messages in, one AccelImpact per detected impact out.

A thin adapter over :class:`vibro_fit.accel_impacts.AccelImpactDetector` (the rule of
``vibro analyze``): zero-phase high-pass, threshold median + k_sigma x robust noise,
refractory time, plate by channel energy, clipping flag. A gap in the block numbering
is reported (log, diagnostics), never silently bridged. vibro/accel is a latched history, so a detector
restarted mid-run detects from block 0 again; blocks of another publisher or run, repeated or going
back, or a history that does not begin at block 0, stop the node (vibro_ros.guard).

Live (``live_accel``: a DAQ driver publishes vibro/accel, docs/live.md *Live accelerometers*): the stream begins
at the first block received, every block is checked (:class:`vibro_fit.live_accel.BlockCheck`: a wrong or
changing rate, unequal channels or stamps going back stop the node with one line, exit code 2; lost blocks and
samples, stamps off the lab clock and clipping are counted and reported on /diagnostics), the detection restarts
after a discontinuity, and each impact is stamped on the lab clock through the blocks' stamps (its ``t_s`` stays
DAQ time).
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
    cpu_nice_parameter,
    declare,
    history_depth_parameter,
    history_qos,
    run_node,
    stamp_from_seconds,
    time_origin_parameter,
)
from vibro_ros.readiness import ReaderGate

from .accel_impacts import AccelImpact as Impact
from .accel_impacts import AccelImpactDetector, warm_up
from .live_accel import LIVE_RATE_GUESS_HZ, AccelStreamRefused, BlockCheck


def impact_message(index: int, impact: Impact, origin_ns: int = 0) -> AccelImpact:
    """The AccelImpact of ``impact``: ``t_s`` DAQ time, the header stamped with it on the lab clock of ``origin_ns``."""
    msg = AccelImpact(index=index, t_s=impact.t_s, plate=impact.plate, peak_ms2=impact.peak_mps2,
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
        self.live = bool(declare(self, "live_accel", False,
                                 "true: vibro/accel comes from a DAQ driver (docs/live.md): the stream begins at the "
                                 "first block received, every block is checked, impacts are stamped through the "
                                 "blocks' lab-clock stamps"))
        rate = float(declare(self, "accel_rate_hz", 0.0, "live: the DAQ's sample rate (Hz); a block at another rate "
                                                          "is refused (0 = the first block's rate)"))
        full_scale = float(declare(self, "accel_full_scale_ms2", 0.0, "live: the sensors' full scale (m/s^2); "
                                                                     "samples at or beyond it are reported clipped "
                                                                     "(0 = not checked)"))
        self.frequency_hz = load_rig(rig_file).excitation.frequency_hz
        self.time_origin_ns = time_origin_parameter(self)
        cpu_nice_parameter(self)
        self.check = BlockCheck(rate, self.time_origin_ns, full_scale) if self.live else None
        if self.live:  # before the subscriptions: a driver that sees this reader matched finds it warm
            warm_up(rate or LIVE_RATE_GUESS_HZ, self.highpass_hz)
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
        # live: on the lab clock through the blocks' stamps (camera time = DAQ time - offset)
        shift = self.check.stamp_offset_s if self.check is not None and self.check.stamp_offset_s is not None else 0.0
        for impact in impacts:
            msg = impact_message(self.sent, impact, self.time_origin_ns)
            if shift:
                stamp_from_seconds(msg.header, impact.t_s - shift, self.time_origin_ns)
            self.pub.publish(msg)
            self.sent += 1
            if impact.clipped:
                self.health.warn(f"impact at {impact.t_s:.5f} s clipped on the {impact.plate} plate's sensor")

    def _on_block(self, msg: AccelBlock) -> None:
        if not self.guard.accept(topics.ACCEL.name, run_id=msg.run_id, index=msg.block_index,
                                 first_index=None if self.live else 0, what="block"):
            return
        if self.check is not None:
            self._on_live_block(msg)
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

    def _on_live_block(self, msg: AccelBlock) -> None:
        """A DAQ driver's block: checked, lost blocks reported, the detection restarted after a discontinuity."""
        try:
            verdict = self.check.check_block(msg)
        except AccelStreamRefused as exc:
            self.guard.fail(f"{topics.ACCEL.name}: {exc}")
            return
        for w in verdict.warnings:
            self.health.warn(w)
            self.get_logger().warning(w)
        if verdict.lost_blocks:
            self.health.count("blocks_lost", verdict.lost_blocks)
        if verdict.lost_samples:
            self.health.count("samples_lost", verdict.lost_samples)
        for channel, k in verdict.clipped_samples.items():
            self.health.count(f"{channel}_clipped_samples", k)
        if verdict.restart and self.detector is not None:  # the high-pass must not run across the discontinuity
            self._publish(self.detector.finish())
            self.detector = AccelImpactDetector(msg.sample_rate_hz, self.frequency_hz, highpass_hz=self.highpass_hz,
                                                k_sigma=self.k_sigma, threshold=self.detector.threshold)
        if self.detector is None:
            self.detector = AccelImpactDetector(msg.sample_rate_hz, self.frequency_hz,
                                                highpass_hz=self.highpass_hz, k_sigma=self.k_sigma)
        n = len(msg.upper_ms2)
        t = msg.t_start_s + np.arange(n) / msg.sample_rate_hz
        self._publish(self.detector.push_block(t, msg.upper_ms2, msg.lower_ms2))
        self.next_block = msg.block_index + 1
        self.health.count("blocks")
        self.health.values["clock_offset_from_stamps_s"] = f"{self.check.stamp_offset_s:.7f}"
        self.health.values["stamp_jitter_s"] = f"{self.check.stamp_jitter_s:.7f}"
        self.health.observe(msg.t_start_s + n / msg.sample_rate_hz)

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
