"""ROS node ``accel_source``: publish a recording's accel.csv as vibro_msgs/AccelBlock messages.

Blocks of ``block_s`` seconds, stamped with the DAQ time of their first sample, either
paced at ``speed`` x real time or (``speed = 0``) as fast as DDS takes them. The stream
is a latched history (reliable, transient local, ``history_depth`` blocks) and blocks are numbered, so
a receiver detects a gap and a node restarted mid-run receives every block again: with
``keep_history_until`` (the node table sets it: its stateful readers' final streams) the source stays
up once done until those readers have ended, because the history lives in the publisher. Each block
carries the run id (parameter ``run_id``).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from rclpy.node import Node

from vibro_io.recording import open_recording
from vibro_model.errors import RecordingError
from vibro_msgs.msg import AccelBlock
from vibro_ros import topics
from vibro_ros.node_support import (
    Health,
    StatusPublisher,
    declare,
    history_depth_parameter,
    history_qos,
    run_id_parameter,
    run_node,
    stamp_from_seconds,
    time_origin_parameter,
)
from vibro_ros.readiness import ReaderGate


class AccelSource(Node):
    def __init__(self) -> None:
        super().__init__("accel_source")
        path = declare(self, "recording", "", "recording directory whose rig.yaml names accel.csv")
        block_s = float(declare(self, "block_s", 0.02, "duration of one published block (s)"))
        self.speed = float(declare(self, "speed", 0.0, "pacing as a multiple of real time; 0 = as fast as possible"))
        self.run_id = run_id_parameter(self)
        self.time_origin_ns = time_origin_parameter(self)
        depth = history_depth_parameter(self)
        if not path:
            raise RecordingError("accel_source: parameter 'recording' is required")
        if block_s <= 0:
            raise RecordingError(f"accel_source: parameter 'block_s' must be > 0, got {block_s}")
        data = open_recording(path).load_accel()
        if data is None:
            raise RecordingError(f"{path}: rig.yaml has no 'accelerometers' block; nothing to publish")
        self.data = data
        self.rate_hz = data.sample_rate_hz
        self.block_n = max(1, int(round(block_s * self.rate_hz)))
        self.starts = np.arange(0, len(data), self.block_n)
        if len(self.starts) > depth:
            self.get_logger().warning(
                f"{len(self.starts)} blocks but history_depth {depth}: a node restarted mid-run cannot receive "
                f"blocks 0..{len(self.starts) - depth - 1} again and will stop with an error")
        self.next_block = 0
        self._t_start: float | None = None
        self.health = Health(self)
        self.health.rate_counter = "blocks"
        self.status = StatusPublisher(self, "accel")
        self.pub = self.create_publisher(AccelBlock, topics.ACCEL.name, history_qos(depth))
        # nothing is sent before every declared reader (impact_detector, trajectory_fitter, recorder) has
        # matched; the node exits once they have acknowledged every block and the end-of-stream status
        self.gate = ReaderGate(self, health=self.health, default_readers=("trajectory_fitter",))
        self.gate.start_clock()
        self.done = self.gate.done
        self._timer = self.create_timer(0.005, self._tick)
        self.get_logger().info(f"{len(data)} samples at {self.rate_hz:.0f} Hz in {len(self.starts)} blocks")

    def _block(self, i: int) -> AccelBlock:
        s = int(self.starts[i])
        e = min(s + self.block_n, len(self.data))
        msg = AccelBlock(block_index=i, first_sample_index=s, sample_rate_hz=self.rate_hz,
                         t_start_s=float(self.data.t_s[s]), run_id=self.run_id)
        msg.upper_ms2 = self.data.upper_ms2[s:e].tolist()
        msg.lower_ms2 = self.data.lower_ms2[s:e].tolist()
        msg.header.frame_id = "daq"
        stamp_from_seconds(msg.header, msg.t_start_s, self.time_origin_ns)
        return msg

    def _tick(self) -> None:
        if self.done.done() or self.next_block >= len(self.starts) > 0:
            return
        if self._t_start is None:
            if not self.gate.open:
                return
            self._t_start = time.monotonic()
        n = len(self.starts)
        due = n if self.speed <= 0 else min(n, int((time.monotonic() - self._t_start) * self.speed
                                                   * self.rate_hz / self.block_n) + 1)
        while self.next_block < due:
            self.pub.publish(self._block(self.next_block))
            self.next_block += 1
            self.health.count("blocks")
        finished = self.next_block >= n
        self.status.publish(self.next_block, 0, finished)
        if finished:
            self.get_logger().info(f"done: {n} blocks published")
            self._timer.cancel()  # nothing left to send: no more wake-ups (the gate polls for the exit)
            self.gate.finish(always=True)


def main(args: list[str] | None = None) -> int:
    return run_node(AccelSource, args)


if __name__ == "__main__":
    sys.exit(main())
