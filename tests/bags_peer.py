"""A separate OS process for tests/test_bags_rosbag2.py: a publisher with a chosen QoS, or a vibro results subscriber.

    python tests/bags_peer.py pub --durability transient_local|volatile --reliability reliable|best_effort
                                  --depth N --tag TAG [--type status|image] [--burst K] [--seconds S]
    python tests/bags_peer.py sub --seconds S      # prints READY, then one JSON list of received (tag, n)

The publisher sends ``burst`` messages at once (kept as history when transient local), then
one more every 0.2 s until ``seconds`` (StreamStatus: stream = tag, items_sent = n; Image:
frame_id = tag, stamp.sec = n). The subscriber listens to vibro/status with
:func:`vibro_ros.adaptive_qos.results_subscription`, as vibro's nodes do.
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("mode", choices=["pub", "sub"])
    parser.add_argument("--durability", default="volatile")
    parser.add_argument("--reliability", default="reliable")
    parser.add_argument("--depth", type=int, default=10)
    parser.add_argument("--tag", default="peer")
    parser.add_argument("--type", choices=["status", "image"], default="status")
    parser.add_argument("--burst", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--node", default="")
    args, _ = parser.parse_known_args()  # --ros-args ... go to rclpy

    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    rclpy.init(args=sys.argv)  # --ros-args (namespace) pass through
    deadline = time.monotonic() + args.seconds
    if args.mode == "pub":
        from sensor_msgs.msg import Image

        from vibro_msgs.msg import StreamStatus

        node = rclpy.create_node(args.node or f"peer_{args.tag}")
        qos = QoSProfile(depth=args.depth, durability=DurabilityPolicy[args.durability.upper()],
                         reliability=ReliabilityPolicy[args.reliability.upper()])
        if args.type == "status":
            pub = node.create_publisher(StreamStatus, "vibro/status", qos)
            make = lambda n: StreamStatus(stream=args.tag, items_sent=n)  # noqa: E731
        else:
            pub = node.create_publisher(Image, "vibro/frames", qos)

            def make(n: int) -> Image:
                msg = Image(height=4, width=4, encoding="mono8", step=4, data=bytes(range(16)))
                msg.header.frame_id, msg.header.stamp.sec = args.tag, n
                return msg
        n = 0
        for n in range(args.burst):
            pub.publish(make(n))
        next_t = time.monotonic()
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
            if time.monotonic() >= next_t:
                n += 1
                pub.publish(make(n))
                next_t += 0.2
        print(json.dumps({"published": n + 1}), flush=True)
        # a driver outlives its last message: leaving at once can free a best-effort sample (shared-memory
        # transport) before a busy reader has taken it, which loses the last frame on a loaded machine
        linger = time.monotonic() + 1.0
        while time.monotonic() < linger:
            rclpy.spin_once(node, timeout_sec=0.05)
    else:
        from rclpy.task import Future

        from vibro_msgs.msg import StreamStatus
        from vibro_ros.adaptive_qos import results_subscription
        from vibro_ros.node_support import make_executor

        node = rclpy.create_node("peer_sub")
        got: list[tuple[str, int]] = []
        results_subscription(node, StreamStatus, "vibro/status", lambda m: got.append((m.stream, int(m.items_sent))))
        executor = make_executor()  # the executor vibro's nodes spin in
        executor.add_node(node)
        print("READY", flush=True)
        while time.monotonic() < deadline:
            executor.spin_until_future_complete(Future(), timeout_sec=0.2)
        print(json.dumps(got), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
