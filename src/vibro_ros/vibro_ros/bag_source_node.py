"""ROS node ``bag_source``: republish a bag's raw topics (frames, accelerometer blocks) for a replay.

Frames are read from ``frames_topic`` (default vibro/frames; a live session's bag holds its camera's topic)
and published on vibro/frames.

Messages go out as recorded (serialized CDR, no re-encoding), stamps included: their lab clock is
the bag's (metadata ``vibro.time_origin_unix_ns``, 0 for an older bag), which ``vibro replay`` gives
every node as ``time_origin_unix_ns``; another nonzero value is refused. Frames are flow-controlled
like ``frame_source`` (never more than ``window`` ahead of the tracker's DicFrames), so a
replay loses nothing; accelerometer blocks go out in order. End-of-stream statuses
"frames" and "accel" carry the counts, as the live sources' do. A bag that holds fewer messages than its
metadata.yaml lists (a file cut short or damaged) is replayed as far as it reads; the messages missing are
announced lost in those statuses (``items_lost``) and logged as an error, so the replay's results say
``complete: false`` with the frames that are missing (:mod:`vibro_app.run_completeness`).
"""

from __future__ import annotations

import sys
import time

from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image

from vibro_io.rig import parse_rig
from vibro_model.errors import RecordingError
from vibro_msgs.msg import AccelBlock, DicFrame
from vibro_ros import topics
from vibro_ros.bags import matching_name, read_custom_data, read_messages, recorded_message_counts
from vibro_ros.guard import InputGuard
from vibro_ros.lab_clock import BAG_TIME_ORIGIN_KEY, TIME_ORIGIN_PARAMETER, origin_from_custom_data
from vibro_ros.node_support import (
    STREAM_QOS,
    Health,
    StatusPublisher,
    declare,
    history_depth_parameter,
    history_qos,
    run_id_parameter,
    run_node,
    seconds_from_stamp,
    time_origin_parameter,
)
from vibro_ros.readiness import ReaderGate


class BagSource(Node):
    def __init__(self) -> None:
        super().__init__("bag_source")
        bag = declare(self, "bag", "", "bag directory recorded by vibro graph")
        self.frames_topic = declare(self, "frames_topic", topics.FRAMES.name,
                                    "the bag's topic of camera images (a live session's camera, e.g. "
                                    "/camera/image_raw); they are replayed on vibro/frames")
        self.window = int(declare(self, "window", 32, "frames in flight before waiting for the tracker"))
        self.linger_s = float(declare(self, "linger_s", 3.0, "seconds to wait for the last acknowledgements"))
        if not bag:
            raise RecordingError("bag_source: parameter 'bag' is required")
        custom = read_custom_data(bag)
        rig_text = custom.get("vibro.rig_yaml")
        if not rig_text:
            raise RecordingError(f"{bag}: the bag's metadata holds no rig.yaml (custom_data 'vibro.rig_yaml')")
        import yaml

        self.camera = parse_rig(yaml.safe_load(rig_text), f"{bag} (recorded rig.yaml)").camera
        try:
            self.recorded_origin_ns = origin_from_custom_data(custom, str(bag))
        except ValueError as exc:
            raise RecordingError(str(exc)) from None
        origin = time_origin_parameter(self)
        if origin not in (0, self.recorded_origin_ns):
            raise RecordingError(f"bag_source: parameter '{TIME_ORIGIN_PARAMETER}' is {origin} but the frames of {bag} "
                                 f"are stamped on origin {self.recorded_origin_ns} (metadata '{BAG_TIME_ORIGIN_KEY}'): "
                                 "the replayed stamps keep it; give every node that origin")
        raw = list(read_messages(bag, {self.frames_topic, topics.ACCEL.name}))
        self.frames = [m.data for m in raw if m.topic == self.frames_topic]
        self.run_id = run_id_parameter(self)
        self.accel = [self._restamped_block(m.data, bag) for m in raw if m.topic == topics.ACCEL.name]
        if not self.frames:
            raise RecordingError(f"{bag}: no {self.frames_topic} messages to replay")
        listed = recorded_message_counts(bag)
        self.frames_lost = self._unreadable(bag, listed, self.frames_topic, len(self.frames))
        self.accel_lost = self._unreadable(bag, listed, topics.ACCEL.name, len(self.accel))
        self.sent = 0
        self.last_index_acked = -1
        self.guard = InputGuard(self)  # the acknowledgements must be this run's tracker's
        self.guard.watch(topics.DIC)
        self._started = False
        self._ended = False
        self._last_progress = time.monotonic()
        self.health = Health(self)
        self.health.rate_counter = "published"
        self.frames_status = StatusPublisher(self, "frames")
        self.accel_status = StatusPublisher(self, "accel")
        self.pub_frames = self.create_publisher(Image, topics.FRAMES.name, STREAM_QOS)
        self.pub_accel = self.create_publisher(AccelBlock, topics.ACCEL.name,
                                               history_qos(history_depth_parameter(self)))
        self.create_subscription(DicFrame, topics.DIC.name, self._on_ack, STREAM_QOS)
        # nothing is sent before every declared reader (dic_tracker, impact_detector, trajectory_fitter,
        # recorder) has matched; the node exits once they have acknowledged everything
        self.gate = ReaderGate(self, health=self.health, default_readers=("dic_tracker",))
        self.gate.start_clock()
        self.done = self.gate.done
        self.create_timer(0.01, self._tick)
        self.get_logger().info(f"{len(self.frames)} frames and {len(self.accel)} accelerometer blocks from {bag}")

    def _unreadable(self, bag: str, counts: dict[str, int], topic: str, read: int) -> int:
        """Messages of ``topic`` that metadata.yaml lists (``counts``) and the bag's files no longer hold (logged
        as an error)."""
        listed = sum(n for name, n in counts.items() if matching_name(name, {topic}))
        lost = max(0, listed - read)
        if lost:
            self.get_logger().error(f"{bag}: {read} of the {listed} {topic} messages its metadata.yaml lists are "
                                    f"readable (the bag is cut short or damaged); replaying those, the other {lost} "
                                    "are announced lost and the results will say so")
        return lost

    def _restamped_block(self, data: bytes, bag: str) -> AccelBlock:
        """A recorded AccelBlock with this run's id (the recorded run's id would be refused as another run's)."""
        try:
            block = deserialize_message(data, AccelBlock)
        except Exception as exc:  # CDR of another AccelBlock definition (a bag recorded by an older vibro)
            raise RecordingError(f"{bag}: a recorded {topics.ACCEL.name} message does not decode as this vibro's "
                                 f"AccelBlock ({exc.__class__.__name__}); was the bag recorded by an older "
                                 "vibro?") from None
        block.run_id = self.run_id
        return block

    def _on_ack(self, msg: DicFrame) -> None:
        if not self.guard.accept(topics.DIC.name, run_id=msg.run_id, index=msg.frame_index, what="frame"):
            return
        self.last_index_acked = max(self.last_index_acked, int(msg.frame_index))
        self._last_progress = time.monotonic()
        self._send_until_index(self.last_index_acked + self.window)

    def _send_until_index(self, limit: int) -> None:
        while self.sent < len(self.frames) and self._indices[self.sent] <= limit:
            self.pub_frames.publish(self.frames[self.sent])
            self.sent += 1
            self.health.count("published")
        if self.sent == len(self.frames):
            self.frames_status.publish(self.sent, self.frames_lost, True)

    def _tick(self) -> None:
        if self.done.done() or self._ended:
            return
        if not self._started:
            if not self.gate.open:
                return
            self._started = True
            # frame numbers from the stamps, as the tracker computes them (k = (t - t0_s) * fps)
            origin = self.recorded_origin_ns
            self._indices = [int(round((seconds_from_stamp(deserialize_message(d, Image).header, origin)
                                        - self.camera.t0_s) * self.camera.fps)) for d in self.frames]
            for data in self.accel:
                self.pub_accel.publish(data)
            self.accel_status.publish(len(self.accel), self.accel_lost, True)
            self._send_until_index(self.window - 1)
            return
        if self.sent < len(self.frames):
            if time.monotonic() - self._last_progress > self.linger_s:  # tracker silent: push on
                self._send_until_index(self._indices[self.sent] + self.window)
                self._last_progress = time.monotonic()
            return
        if self.last_index_acked >= self._indices[-1] or time.monotonic() - self._last_progress > self.linger_s:
            self.frames_status.publish(self.sent, self.frames_lost, True)
            self.get_logger().info(f"done: {self.sent} frames, {len(self.accel)} accelerometer blocks replayed")
            self._ended = True
            self.gate.finish(always=True)


def main(args: list[str] | None = None) -> int:
    return run_node(BagSource, args)


if __name__ == "__main__":
    sys.exit(main())
