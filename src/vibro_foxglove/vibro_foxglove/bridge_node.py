"""ROS node ``foxglove_bridge``: the graph's topics on a Foxglove WebSocket server, for a lab's own screen.

A thin adapter over :mod:`vibro_foxglove.view` (the conversions and the server): it subscribes to
the graph's topics and republishes them as Foxglove channels (camera frames as foxglove.RawImage with
foxglove.ImageAnnotations of the tracked ROIs, the DIC track, impacts with COR, fits, D, findings and
diagnostics as JSON). It never slows the graph: every subscription is best effort and keep-last (the
frames' depth 1), it is no node's declared reader (nobody waits for it), frames are only deserialized when
the frame rate limit lets one through, and a slow or absent Foxglove client only loses its own oldest
messages (the server's per-client backlog). From a recording (``exit_when_done``) it exits once the graph's
nodes have gone (no vibro/status publisher left for ``linger_s``); live it stays up with the graph.
"""

from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.task import Future
from sensor_msgs.msg import Image

from vibro_foxglove import view as fv
from vibro_io.rig import load_rig
from vibro_model.errors import RecordingError
from vibro_msgs.msg import DicFrame, DiscrepancyFinding, FreeFlight, ImpactEstimate, SimulationResult, StructureMotion
from vibro_ros import topics
from vibro_ros.lab_clock import data_time_from_stamp_ns
from vibro_ros.node_support import Health, declare, run_node, time_origin_parameter

#: Queue depths of the bridge's readers: frames 1 (only the newest matters), streams STREAM_DEPTH, results
#: RESULTS_DEPTH. Best effort: a depth costs the publisher nothing, the reader only drops when it falls behind.
STREAM_DEPTH = 100
RESULTS_DEPTH = 1000


def best_effort(depth: int) -> QoSProfile:
    """A best-effort, volatile, keep-last reader: it matches any publisher and never makes one wait."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def _check_parameters(port: int, max_rate_hz: float, backlog: int, channels: list[str]) -> None:
    """RecordingError naming the parameter for a bad ``port``, ``max_frame_rate_hz`` (frames/s),
    ``client_backlog`` (messages) or an unknown channel in ``topics``."""
    if not 0 <= port <= 65535:
        raise RecordingError(f"foxglove_bridge: parameter 'port' must be 0-65535, got {port}")
    if not max_rate_hz >= 0:
        raise RecordingError(f"foxglove_bridge: parameter 'max_frame_rate_hz' must be >= 0, got {max_rate_hz}")
    if backlog < 1:
        raise RecordingError(f"foxglove_bridge: parameter 'client_backlog' must be >= 1, got {backlog}")
    unknown = sorted(set(channels) - set(fv.CHANNELS_BY_TOPIC))
    if unknown:
        raise RecordingError(f"foxglove_bridge: parameter 'topics' has unknown channels {unknown} "
                             f"(known: {', '.join(fv.CHANNELS_BY_TOPIC)})")


class FoxgloveBridge(Node):
    def __init__(self) -> None:
        super().__init__("foxglove_bridge")
        port = int(declare(self, "port", fv.DEFAULT_PORT, "TCP port of the Foxglove WebSocket server (0 = any free)"))
        host = str(declare(self, "host", "0.0.0.0",
                           "address the server listens on: 0.0.0.0 = every interface (another PC's Foxglove app), "
                           "127.0.0.1 = this PC only"))
        max_rate_hz = float(declare(self, "max_frame_rate_hz", 15.0,
                                    "camera frames sent to Foxglove per second of wall time at most (0 = every "
                                    "frame); the DIC track and results are never decimated"))
        channels = [c for c in declare(self, "topics", list(fv.CHANNELS_BY_TOPIC),
                                       "Foxglove channels to serve: " + ", ".join(fv.CHANNELS_BY_TOPIC)) if c]
        rig_file = str(declare(self, "rig_file", "", "rig.yaml of the recording: ROIs and scale for the image "
                                                     "annotations (empty: frames without annotations)"))
        backlog = int(declare(self, "client_backlog", 512, "messages queued per Foxglove client; a client that "
                                                            "falls further behind loses its oldest ones"))
        self.exit_when_done = bool(declare(self, "exit_when_done", False,
                                           "exit once the graph's nodes have gone (from a recording); "
                                           "false: stay up (live)"))
        self.linger_s = float(declare(self, "linger_s", 2.0, "s to keep serving after the graph's nodes have gone "
                                                             "(exit_when_done)"))
        _check_parameters(port, max_rate_hz, backlog, channels)
        self.geometry = self._image_geometry(rig_file, channels)
        self.origin_ns = time_origin_parameter(self)
        self.throttle = fv.FrameThrottle(max_rate_hz)
        self.sent_frames: dict[int, int] = {}  # frame index -> stamp (ns) of the image sent, the latest few
        self.last_impact = None
        self.health = Health(self)
        self.health.rate_counter = "frames_received"
        try:
            self.server = fv.FoxgloveServer(host, port, channels, name=f"vibro {self.get_namespace()}",
                                            backlog=backlog)
        except Exception as exc:  # the SDK's error names the address (e.g. in use)
            raise RecordingError(f"foxglove_bridge: cannot serve on {host}:{port}: {exc}") from None
        self.url = fv.websocket_url(host, self.server.port)
        self.get_logger().info(f"Foxglove WebSocket server on {self.url} (channels: {', '.join(channels)})")
        self.health.values["url"] = self.url

        self._subscribe(set(channels))
        self.saw_graph = False
        self.graph_gone_since: float | None = None
        self.done = Future()
        self.create_timer(0.1, self._tick)

    def _image_geometry(self, rig_file: str, channels: list[str]) -> fv.ImageGeometry | None:
        """The image annotations' geometry (ROIs, scale) from ``rig_file``; without one, the annotations channel
        is dropped from ``channels`` (with a warning) and None returned."""
        if rig_file:
            return fv.ImageGeometry.from_rig(load_rig(rig_file))
        if fv.ANNOTATIONS.topic in channels:
            self.get_logger().warning("parameter 'rig_file' not set: frames are served without annotations")
            channels.remove(fv.ANNOTATIONS.topic)
        return None

    def _subscribe(self, served: set[str]) -> None:
        """Subscribe (best effort) to the graph topics behind the ``served`` Foxglove channels."""
        if fv.FRAMES.topic in served:  # raw: deserialized only when the rate limit lets the frame through
            self.create_subscription(Image, topics.FRAMES.name, self._on_frame, best_effort(1), raw=True)
        if served & {fv.TRACK.topic, fv.ANNOTATIONS.topic}:
            self.create_subscription(DicFrame, topics.DIC.name, self._on_dic, best_effort(STREAM_DEPTH))
        # results come in bursts (every final impact at once): deep queues, so a burst does not overwrite itself
        if fv.IMPACTS.topic in served:
            self.create_subscription(ImpactEstimate, topics.IMPACTS.name, self._on_impact, best_effort(RESULTS_DEPTH))
        if fv.IMPACTS_FINAL_MODEL.topic in served:
            self.create_subscription(ImpactEstimate, topics.IMPACTS_FINAL_MODEL.name,
                                     lambda m: self._send(fv.impact_payload(m, fv.IMPACTS_FINAL_MODEL)),
                                     best_effort(RESULTS_DEPTH))
        if fv.STRUCTURE.topic in served:
            self.create_subscription(StructureMotion, topics.STRUCTURE.name,
                                     lambda m: self._send(fv.structure_payload(m)), best_effort(RESULTS_DEPTH))
        if fv.FLIGHTS.topic in served:
            self.create_subscription(FreeFlight, topics.FLIGHTS.name, lambda m: self._send(fv.flight_payload(m)),
                                     best_effort(RESULTS_DEPTH))
        if fv.SIMULATION.topic in served:
            self.create_subscription(SimulationResult, topics.SIMULATION.name,
                                     lambda m: self._send(fv.simulation_payload(m)), best_effort(RESULTS_DEPTH))
        if fv.DISCREPANCY.topic in served:
            self.create_subscription(DiscrepancyFinding, topics.DISCREPANCY.name,
                                     lambda m: self._send(fv.discrepancy_payload(m)), best_effort(RESULTS_DEPTH))
        if fv.DIAGNOSTICS.topic in served:
            self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS.name, self._on_diagnostics,
                                     best_effort(STREAM_DEPTH))

    # ------------------------------------------------------------------ callbacks
    def _send(self, payload: fv.Payload) -> None:
        self.server.publish(payload)
        self.health.count("messages_sent")

    def _on_frame(self, raw: bytes) -> None:
        self.health.count("frames_received")
        if not self.throttle.allow(time.monotonic()):
            return
        from vibro_dic.dic_tracker_node import image_array

        msg = deserialize_message(raw, Image)
        try:
            pixels = image_array(msg)
        except RecordingError as exc:
            self.health.warn(f"frame not shown: {exc}")
            return
        stamp = fv.stamp_ns(msg.header)
        self._send(fv.frame_payload(pixels, stamp, msg.header.frame_id or "camera"))
        self.health.count("frames_sent")
        if self.geometry is not None:
            index = self.geometry.frame_index(data_time_from_stamp_ns(self.origin_ns, stamp))
            self.sent_frames[index] = stamp
            while len(self.sent_frames) > 256:
                self.sent_frames.pop(next(iter(self.sent_frames)))

    def _on_dic(self, msg: DicFrame) -> None:
        self._send(fv.track_payload(msg))
        stamp = self.sent_frames.pop(int(msg.frame_index), None)
        if stamp is not None and fv.ANNOTATIONS.topic in self.server.channels:
            self._send(fv.annotations_payload(msg, stamp, self.geometry, self.last_impact))

    def _on_impact(self, msg: ImpactEstimate) -> None:
        self.last_impact = msg
        self._send(fv.impact_payload(msg))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for payload in fv.diagnostics_payloads(msg, self.get_namespace()):
            self._send(payload)

    def _tick(self) -> None:
        self.server.replay_pending()
        self.health.values["cpu_s"] = f"{time.process_time():.3f}"  # what watching costs the machine's cores
        if not self.exit_when_done or self.done.done():
            return
        # the graph's nodes publish vibro/status in this namespace; once all have gone (for linger_s), exit
        present = self.count_publishers(topics.STATUS.name) > 0
        now = time.monotonic()
        if present:
            self.saw_graph, self.graph_gone_since = True, None
        elif self.saw_graph:
            self.graph_gone_since = self.graph_gone_since or now
            if now - self.graph_gone_since >= self.linger_s:
                self.get_logger().info("the graph's nodes have gone: stopping the Foxglove server")
                self.done.set_result(True)

    def close(self) -> None:
        self.server.close()


def main(args: list[str] | None = None) -> int:
    return run_node(FoxgloveBridge, args)


if __name__ == "__main__":
    sys.exit(main())
