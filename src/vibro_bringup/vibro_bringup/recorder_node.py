"""ROS node ``recorder``: every vibro topic, as received (serialized CDR), into a rosbag2/MCAP bag.

Writes chunk by chunk and rewrites metadata.yaml every second, so a killed recorder
leaves a bag readable up to its last chunk. Stops cleanly (index + final metadata) on
SIGINT/SIGTERM.
"""

from __future__ import annotations

import importlib
import sys

from rclpy.node import Node

from vibro_ros import topics
from vibro_ros.bags import BagWriter
from vibro_io.errors import RecordingError
from vibro_ros.node_support import QOS_BY_KIND, Health, declare, run_node
from vibro_ros.readiness import WriterWatch


def message_class(ros_type: str):
    """The Python class of ``pkg/msg/Type``."""
    pkg, _, name = ros_type.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


class Recorder(Node):
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
        self.writer = BagWriter(bag, chunk_size=chunk_kb * 1024, custom_data=custom,
                                compression=compression)
        self.health = Health(self)
        self.health.rate_counter = "recorded"
        for topic in topics.ALL_TOPICS:
            if topic.name in exclude:
                continue
            self.writer.add_topic(topic.name, topic.msg_type)
            self.create_subscription(message_class(topic.msg_type), topic.name,
                                     lambda data, name=topic.name: self._on_message(name, data),
                                     QOS_BY_KIND.get(topic.qos, 10), raw=True)
        self.get_logger().info(f"recording {len(self.writer.topics)} topics to {bag}")
        # file mode: ends once every declared writer has come and gone (they wait for this recorder)
        self.inputs = WriterWatch(self, list(self.writer.topics))
        self.done = self.inputs.done

    def _on_message(self, topic: str, data: bytes) -> None:
        self.writer.write(topic, self.get_clock().now().nanoseconds, data)
        self.health.count("recorded")

    def close(self) -> None:
        self.writer.close()
        print(f"recorder: closed {self.writer.path}: {self.writer.message_count} messages", file=sys.stderr)


def main(args: list[str] | None = None) -> int:
    return run_node(Recorder, args)


if __name__ == "__main__":
    sys.exit(main())
