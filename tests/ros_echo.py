"""A separate OS process that prints every message of one topic as a JSON line.

    python tests/ros_echo.py vibro_msgs/msg/DicFrame vibro/dic --count 5 --seconds 30 [--qos stream|results]
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ros_peer import to_plain  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("msg_type")
    parser.add_argument("topic")
    parser.add_argument("--count", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--qos", choices=["stream", "results"], default="stream")
    args = parser.parse_args()

    import rclpy

    from vibro_ros.node_support import QOS_BY_KIND

    pkg, _, name = args.msg_type.split("/")
    cls = getattr(importlib.import_module(f"{pkg}.msg"), name)
    rclpy.init()
    node = rclpy.create_node("vibro_test_echo")
    got = []

    def on_msg(msg) -> None:
        got.append(msg)
        print(json.dumps(to_plain(msg)), flush=True)

    node.create_subscription(cls, args.topic, on_msg, QOS_BY_KIND[args.qos])
    print("READY", flush=True)
    deadline = time.monotonic() + args.seconds
    while time.monotonic() < deadline and len(got) < args.count:
        rclpy.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
