"""A separate OS process that plays a foreign camera: it publishes images on a vibro run's frames topic.

    python tests/ros_intruder.py /NAMESPACE --t0 0.0 --fps 1000 --frame 5 [--seconds 60]

Node ``intruder_camera`` in NAMESPACE publishes a small mono8 image stamped as frame FRAME
(t0 + FRAME / fps) ten times a second on NAMESPACE/vibro/frames; prints READY once a subscriber
(the run's dic_tracker) has matched.
"""

from __future__ import annotations

import argparse
import sys
import time


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("namespace")
    parser.add_argument("--t0", type=float, default=0.0)
    parser.add_argument("--fps", type=float, default=1000.0)
    parser.add_argument("--frame", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()

    import rclpy
    from sensor_msgs.msg import Image

    from vibro_ros import topics
    from vibro_ros.node_support import STREAM_QOS, stamp_from_seconds

    rclpy.init()
    node = rclpy.create_node("intruder_camera", namespace=args.namespace)
    pub = node.create_publisher(Image, topics.FRAMES.name, STREAM_QOS)
    msg = Image(height=8, width=8, encoding="mono8", is_bigendian=0, step=8, data=bytes(64))
    stamp_from_seconds(msg.header, args.t0 + args.frame / args.fps)
    deadline = time.monotonic() + args.seconds
    ready = False
    while time.monotonic() < deadline:
        if not ready and pub.get_subscription_count() > 0:
            ready = True
            print("READY", flush=True)
        if ready:
            pub.publish(msg)
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
