"""ROS node ``frame_source``: publish a recording's frames as ``sensor_msgs/Image``.

Stamps are camera time (t0_s + k/fps) on the lab clock (+ ``time_origin_unix_ns``,
:mod:`vibro_ros.lab_clock`), so a subscriber recovers the frame index from the stamp, exactly
as with a live camera driver. With ``rate_hz = 0`` it sends as fast as
the DIC tracker keeps up, never more than ``window`` frames ahead of the tracker's
acknowledgements (its DicFrame messages): no frame is ever dropped. A frame that cannot be
read is reported (log, diagnostics, StreamStatus.items_lost) and the tracker sees the gap.
"""

from __future__ import annotations

import sys
import time

from rclpy.node import Node
from sensor_msgs.msg import Image

from vibro_io.frames import Frame
from vibro_io.recording import open_recording
from vibro_model.errors import RecordingError
from vibro_msgs.msg import DicFrame
from vibro_ros import topics
from vibro_ros.guard import InputGuard
from vibro_ros.node_support import (
    STREAM_QOS,
    Health,
    StatusPublisher,
    declare,
    run_node,
    stamp_from_seconds,
    stop_requested,
    time_origin_parameter,
)
from vibro_ros.readiness import ReaderGate


def image_message(frame: Frame, frame_id: str, origin_ns: int = 0) -> Image:
    """A mono8/mono16 Image of ``frame`` stamped with its camera time on the lab clock of ``origin_ns``
    (:mod:`vibro_ros.lab_clock`)."""
    img = frame.image
    msg = Image(height=img.shape[0], width=img.shape[1], is_bigendian=0)
    msg.encoding = "mono8" if img.dtype.itemsize == 1 else "mono16"
    msg.step = img.shape[1] * img.dtype.itemsize
    msg.data = img.tobytes()
    msg.header.frame_id = frame_id
    stamp_from_seconds(msg.header, frame.t_s, origin_ns)
    return msg


class FrameSource(Node):
    def __init__(self) -> None:
        super().__init__("frame_source")
        path = declare(self, "recording", "", "recording directory (rig.yaml and frames/ or video.avi)")
        self.rate_hz = float(declare(self, "rate_hz", 0.0,
                                     "frames/s to publish at; 0 = as fast as the tracker acknowledges (lossless)"))
        self.window = int(declare(self, "window", 32, "frames in flight before waiting for the tracker (rate_hz = 0)"))
        self.frame_id = declare(self, "frame_id", "camera", "header.frame_id of the images")
        self.time_origin_ns = time_origin_parameter(self)
        self.linger_s = float(declare(self, "linger_s", 3.0,
                                      "seconds to wait for the last acknowledgements before exiting"))

        if not path:
            raise RecordingError("frame_source: parameter 'recording' is required")
        if self.window < 1:
            raise RecordingError(f"frame_source: parameter 'window' must be >= 1, got {self.window}")
        if self.rate_hz < 0:
            raise RecordingError(f"frame_source: parameter 'rate_hz' must be >= 0, got {self.rate_hz}")
        self.recording = open_recording(path)
        self.total = len(self.recording.frames)
        self._frames = iter(self.recording.frames)
        self.sent = self.lost = self.acked = 0
        self.last_index_sent = -1
        self.last_index_acked = -1
        self.exhausted = False
        self._acked_or_lingered = False
        self._started_at: float | None = None
        self._last_progress = time.monotonic()
        self.health = Health(self)
        self.health.rate_counter = "published"
        self.health.values["frames_total"] = self.total
        self.status = StatusPublisher(self, "frames")
        self.guard = InputGuard(self)  # the acknowledgements must be this run's tracker's
        self.guard.watch(topics.DIC)
        self.pub = self.create_publisher(Image, topics.FRAMES.name, STREAM_QOS)
        self.create_subscription(DicFrame, topics.DIC.name, self._on_ack, STREAM_QOS)
        # nothing is sent before every declared reader (dic_tracker, recorder) has matched
        self.gate = ReaderGate(self, health=self.health, default_readers=("dic_tracker",))
        self.gate.start_clock()
        self.done = self.gate.done
        self._timer = self.create_timer(0.01, self._tick)
        self.get_logger().info(f"{self.total} frames from {self.recording.frames.source}")

    def _on_ack(self, msg: DicFrame) -> None:
        if not self.guard.accept(topics.DIC.name, run_id=msg.run_id, index=msg.frame_index, what="frame"):
            return
        self.acked += 1
        self.last_index_acked = max(self.last_index_acked, int(msg.frame_index))
        self._last_progress = time.monotonic()
        if self.rate_hz <= 0:
            # the tracker answers every frame slot (gaps too), so its last index paces the window; slots are
            # counted from the recording's first frame number (frame 0 may be missing)
            answered = self.last_index_acked + 1 - self.recording.frames.first_index
            self._send_until(answered + self.window)

    def _send_one(self) -> bool:
        """Publish the next readable frame; False when the recording is exhausted."""
        for frame in self._frames:
            if frame.ok:
                self.pub.publish(image_message(frame, self.frame_id, self.time_origin_ns))
                self.sent += 1
                self.last_index_sent = frame.index
                self.health.count("published")
                self.health.observe(frame.t_s)
                return True
            self.lost += 1
            self.health.count("unreadable")
            self.health.warn(f"frame {frame.index} not published: {frame.error}")
            self.get_logger().warning(f"frame {frame.index} not published: {frame.error}")
        self.exhausted = True
        return False

    def _send_until(self, limit: int) -> None:
        # a stop signal ends the burst: a reliable publish to readers that died blocks (history full), and a
        # burst of them kept the node from seeing SIGINT for seconds (launch escalated to SIGTERM)
        while not self.exhausted and self.sent + self.lost < limit and not stop_requested():
            if not self._send_one():
                break
        if self.exhausted:
            self.status.publish(self.sent, self.lost, True)

    def _tick(self) -> None:
        if self.done.done() or self._acked_or_lingered:
            return
        if self._started_at is None:
            if not self.gate.open:
                return
            self._started_at = time.monotonic()
            self._last_progress = self._started_at
            self.get_logger().info(f"streaming: {self.pub.get_subscription_count()} subscribers matched")
        if not self.exhausted:
            if self.rate_hz > 0:
                due = int((time.monotonic() - self._started_at) * self.rate_hz) + 1
                self._send_until(due)
            elif self.sent == 0 or time.monotonic() - self._last_progress > self.linger_s:
                # start the window, or push on when the tracker stopped acknowledging (it reports the gap)
                self._send_until(self.sent + self.lost + self.window)
                self._last_progress = time.monotonic()
            self.status.publish(self.sent, self.lost, self.exhausted)
            return
        all_acked = self.last_index_acked >= self.last_index_sent
        if all_acked or time.monotonic() - self._last_progress > self.linger_s:
            self.status.publish(self.sent, self.lost, True)
            self.get_logger().info(
                f"done: {self.sent} published, {self.lost} unreadable, {self.acked} acknowledged of {self.total}")
            self._acked_or_lingered = True
            self._timer.cancel()  # nothing left to send or await: no more wake-ups (the gate polls for the exit)
            self.gate.finish(always=True)


def main(args: list[str] | None = None) -> int:
    return run_node(FrameSource, args)


if __name__ == "__main__":
    sys.exit(main())
