"""ROS node ``recorder``: every vibro topic, as received (serialized CDR), into a rosbag2/MCAP bag.

Every topic is subscribed at start with the topic table's profile (sources wait for the
recorder), and, as ``ros2 bag record`` adapts its request, a publisher that profile cannot
match (a best-effort camera driver, a volatile replay of a result topic) gets a companion
reader that matches it (:class:`vibro_ros.adaptive_qos.ResultsSubscription`): nothing
offered is left unrecorded, and transient-local results still arrive late. The bag stores
fully qualified names and, per topic, the profiles its publishers offered (discovered when
its first publisher appears; messages are held until then).
Finishes a chunk at least once a second and rewrites metadata.yaml every second, so a
killed recorder leaves a bag readable up to its last chunk (``vibro bag reindex`` then
indexes it). Stops cleanly (index + final metadata) on SIGINT/SIGTERM.
"""

from __future__ import annotations

import importlib
import sys
import time

from rclpy.node import Node

from vibro_io.camera_calibration import calibration_custom_data
from vibro_model.errors import RecordingError
from vibro_ros import topics
from vibro_ros.adaptive_qos import ResultsSubscription, discovered_offers, publishers_identified
from vibro_ros.bags import BagWriter
from vibro_ros.lab_clock import BAG_TIME_ORIGIN_KEY
from vibro_ros.node_support import QOS_BY_KIND, Health, declare, run_node, time_origin_parameter
from vibro_ros.qos_format import adapt_request_to_offers
from vibro_ros.readiness import WriterWatch

#: How often the recorder looks for publishers of the topics it does not record yet (s), as rosbag2.
DISCOVERY_S = 0.1
#: How long to wait for a discovered publisher's node name (to recognise vibro's own publishers) (s); the
#: messages that arrive meanwhile are held, not lost. A loaded machine names an endpoint's node seconds after
#: the endpoint (a CI run: not within 1 s, vibro_ros.guard); the wait ends as soon as the name is known.
NAME_WAIT_S = 5.0


def message_class(ros_type: str):
    """The Python class of ``pkg/msg/Type``."""
    pkg, _, name = ros_type.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class Recorder(Node):
    #: rclpy's SingleThreadedExecutor: under rclpy 7.1's EventsExecutor the recorder's timers (17: topic
    #: discovery, flushing, end of inputs, one per adaptive subscription) were seen to stop firing for 10-60 s
    #: while its subscriptions still ran (1 of 6 loaded runs; 0 of 9 with this executor), so the bag stayed
    #: open long after every writer had gone (a CI timeout)
    EXECUTOR = "single"

    def __init__(self) -> None:
        super().__init__("recorder")
        bag = declare(self, "bag", "", "bag directory to create (rosbag2, MCAP storage)")
        chunk_kb = int(declare(self, "chunk_kb", 512, "MCAP chunk size (KiB); a kill loses at most one chunk"))
        exclude = list(declare(self, "exclude_topics", [""], "topics not to record (e.g. vibro/frames)"))
        compression = declare(self, "compression", "lz4",
                              "MCAP chunk compression: lz4 (fast), zstd (smaller, ~3x the CPU) or none")
        rig_file = declare(self, "rig_file", "", "rig.yaml stored in the bag's metadata (custom_data) for replay")
        if not bag:
            raise RecordingError("recorder: parameter 'bag' is required")
        custom = {}
        if rig_file:
            from pathlib import Path

            custom["vibro.rig_yaml"] = Path(rig_file).read_text(encoding="utf-8")
            custom.update(calibration_custom_data(rig_file))  # rig.yaml's camera.calibration, for a replay
        # the lab clock of the header stamps (stamp = origin + data time), so a replay stamps identically
        custom[BAG_TIME_ORIGIN_KEY] = str(time_origin_parameter(self))
        self.writer = BagWriter(bag, chunk_size=chunk_kb * 1024, custom_data=custom,
                                compression=compression)
        self.health = Health(self)
        self.health.rate_counter = "recorded"
        #: fully qualified name -> topic, until its publishers are discovered and its channel is written
        self.pending = {self.resolve_topic_name(t.name): t for t in topics.ALL_TOPICS
                        if t.name not in exclude and self.resolve_topic_name(t.name) not in exclude}
        self._held: dict[str, list[tuple[int, bytes]]] = {name: [] for name in self.pending}
        self._first_seen: dict[str, float] = {}
        # subscribed at once with the topic table's profile, so sources waiting for the recorder see it;
        # a publisher that profile cannot match (best-effort camera, volatile replay) gets a companion reader
        self.subscriptions_by_topic = {}
        for topic in topics.ALL_TOPICS:
            name = self.resolve_topic_name(topic.name)
            if name in self.pending:
                self.subscriptions_by_topic[name] = ResultsSubscription(
                    self, message_class(topic.msg_type), topic.name, lambda data, n=name: self._on_message(n, data),
                    QOS_BY_KIND[topic.qos], raw=True)
        self.create_timer(DISCOVERY_S, self._tick)  # one timer: each costs the executor a wake-up
        self.get_logger().info(f"recording {', '.join(sorted(self.pending))} to {bag}")
        # file mode: ends once every declared writer has come and gone (they wait for this recorder)
        self.received: dict[str, int] = {}  # fully qualified topic -> messages received
        stream_topic = {t.name.rsplit("/", 1)[-1]: self.resolve_topic_name(t.name) for t in topics.ALL_TOPICS}
        self.inputs = WriterWatch(self, list(self.pending),
                                  received=lambda stream: self._received(stream_topic, stream))
        self.done = self.inputs.done

    def _received(self, stream_topic: dict[str, str], stream: str) -> int | None:
        """Messages received on ``stream``'s topic (None: a topic this recorder does not record)."""
        topic = stream_topic.get(stream, "")
        return self.received.get(topic, 0) if topic in self.subscriptions_by_topic else None

    def _tick(self) -> None:
        self._discover()
        self.writer.flush_if_due()  # a quiet topic's last messages reach the disk within a second
        self.inputs.poll()          # have the writers come and gone

    def _discover(self, final: bool = False) -> None:
        """Write the channel of each topic whose publishers are discovered, with their offered profiles."""
        for name, topic in list(self.pending.items()):
            if not final:
                if not self.count_publishers(name):
                    continue
                now = time.monotonic()
                if not publishers_identified(self, name) and now - self._first_seen.setdefault(name, now) < NAME_WAIT_S:
                    continue  # history/depth of vibro's own publishers are recognised by their node name
            elif not self._held[name]:
                continue
            offers = discovered_offers(self, name, QOS_BY_KIND[topic.qos], topic.nodes)
            self.writer.add_topic(name, topic.msg_type, offers)
            del self.pending[name]
            for stamp_ns, data in self._held.pop(name):
                self._write(name, stamp_ns, data)
            reliability, durability = adapt_request_to_offers(offers)
            self.get_logger().info(f"recording {name}: {len(offers)} publisher(s), matched as {reliability}, "
                                   f"{durability}")

    def _on_message(self, topic: str, data: bytes) -> None:
        stamp_ns = self.get_clock().now().nanoseconds
        self.received[topic] = self.received.get(topic, 0) + 1
        held = self._held.get(topic)
        if held is not None:  # channel not written yet: its publishers' QoS is still being discovered
            held.append((stamp_ns, data))
        else:
            self._write(topic, stamp_ns, data)

    def _write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        self.writer.write(topic, stamp_ns, data)
        self.health.count("recorded")

    def close(self) -> None:
        self._discover(final=True)  # messages received before their publishers were identified
        self.writer.close()
        print(f"recorder: closed {self.writer.path}: {self.writer.message_count} messages", file=sys.stderr)


def main(args: list[str] | None = None) -> int:
    return run_node(Recorder, args)


if __name__ == "__main__":
    sys.exit(main())
