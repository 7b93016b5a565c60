"""A separate OS process that publishes or receives every vibro_msgs type over DDS.

    python tests/ros_peer.py pub [--seconds 60]
    python tests/ros_peer.py sub [--seconds 60]     # prints one JSON object, then exits

The publisher fills every field of every type from :func:`sample_message`; the
subscriber prints what it received, field by field, so the test can compare.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import vibro_msgs.msg as vm

MSG_TYPES = [
    vm.DicFrame, vm.AccelBlock, vm.AccelImpact, vm.StructureMotion, vm.FreeFlight,
    vm.ImpactEstimate, vm.SimulationResult, vm.DiscrepancyFinding, vm.StreamStatus,
]


def _value(field_type: str, seed: int):
    """A deterministic, exactly representable value for a rosidl field type."""
    if field_type.startswith("sequence<"):
        inner = field_type[len("sequence<"):-1]
        return [_value(inner, seed + i) for i in range(3 + seed % 4)]
    if field_type == "string":
        return f"text-{seed}-top"
    if field_type == "boolean":
        return seed % 2 == 1
    if field_type in ("double", "float"):
        return seed * 0.25 - 3.5  # multiples of 1/4 are exact in float32 too
    if field_type.startswith("uint") or field_type.startswith("int"):
        return seed * 7 + 1
    raise TypeError(field_type)


def sample_message(cls, seed: int = 1):
    """An instance of ``cls`` with every field set (nested Header too)."""
    msg = cls()
    for i, (name, ftype) in enumerate(msg.get_fields_and_field_types().items()):
        if ftype == "std_msgs/Header":
            msg.header.stamp.sec = 1000 + seed
            msg.header.stamp.nanosec = 500_000 + i
            msg.header.frame_id = f"camera-{seed}"
        else:
            setattr(msg, name, _value(ftype, seed + i))
    return msg


def to_plain(msg) -> dict:
    """Field values of a received message as JSON-able Python values."""
    out = {}
    for name, ftype in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if ftype == "std_msgs/Header":
            out[name] = [value.stamp.sec, value.stamp.nanosec, value.frame_id]
        elif ftype.startswith("sequence<") and "/" in ftype:  # nested messages
            out[name] = [to_plain(v) for v in value]
        elif ftype.startswith("sequence<"):
            out[name] = [float(v) if isinstance(v, float) or hasattr(v, "dtype") else v for v in list(value)]
        elif isinstance(value, float):
            out[name] = float(value)
        elif isinstance(value, bytes) and len(value) == 1:  # a `byte` field
            out[name] = value[0]
        else:
            out[name] = value
    return out


def topic_of(cls) -> str:
    return "vibro_test/" + cls.__name__.lower()


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("mode", choices=["pub", "sub"])
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()

    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    rclpy.init()
    node = rclpy.create_node(f"vibro_test_{args.mode}")
    deadline = time.monotonic() + args.seconds
    if args.mode == "pub":
        pubs = [(node.create_publisher(cls, topic_of(cls), qos), sample_message(cls)) for cls in MSG_TYPES]
        while time.monotonic() < deadline:
            for pub, msg in pubs:
                pub.publish(msg)
            rclpy.spin_once(node, timeout_sec=0.1)
    else:
        received: dict[str, dict] = {}
        for cls in MSG_TYPES:
            node.create_subscription(
                cls, topic_of(cls),
                lambda m, name=cls.__name__: received.setdefault(name, to_plain(m)), qos)
        print("READY", flush=True)
        while time.monotonic() < deadline and len(received) < len(MSG_TYPES):
            rclpy.spin_once(node, timeout_sec=0.1)
        print(json.dumps(received), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
