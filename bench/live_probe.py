"""The measuring subscriber of bench_live: arrival wall times on vibro/dic and vibro/impacts.

    python bench/live_probe.py OUT.json READY_FILE [--idle-s 3] [--max-s 120] --ros-args -r __node:=bench_probe

Records, per DicFrame, (arrival wall time s, frame_index, lost, status) and, per ImpactEstimate,
(arrival wall time s, index, t_s, final), per AccelImpact (arrival, index, t_s DAQ time).
Touches READY_FILE once vibro/dic and vibro/impacts each
have a publisher, so the bench starts the camera only when it can listen. Ends by itself when no
DicFrame arrived for ``--idle-s`` after the first one (or after ``--max-s``), then writes OUT.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future

from vibro_msgs.msg import AccelImpact, DicFrame, ImpactEstimate
from vibro_ros import topics
from vibro_ros.node_support import RESULTS_QOS, make_executor, spin_until_done

#: Reliable, volatile, deep: matches the tracker's latched history without asking for it again.
DIC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100_000, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("ready", type=Path)
    parser.add_argument("--idle-s", type=float, default=3.0)
    parser.add_argument("--max-s", type=float, default=120.0)
    args = parser.parse_args(rclpy.utilities.remove_ros_args(argv)[1:])
    rclpy.init(args=argv)
    node = rclpy.create_node("bench_probe")
    dic: list[tuple[float, int, bool, str]] = []
    impacts: list[tuple[float, int, float, bool]] = []
    node.create_subscription(DicFrame, topics.DIC.name,
                             lambda m: dic.append((time.time(), m.frame_index, m.lost, m.status)), DIC_QOS)
    node.create_subscription(ImpactEstimate, topics.IMPACTS.name,
                             lambda m: impacts.append((time.time(), m.index, m.t_s, m.final)), RESULTS_QOS)
    accel: list[tuple[float, int, float]] = []
    node.create_subscription(AccelImpact, topics.ACCEL_IMPACTS.name,
                             lambda m: accel.append((time.time(), m.index, m.t_s)), RESULTS_QOS)
    done = Future()
    started = time.monotonic()

    def check() -> None:
        if not args.ready.exists() and node.count_publishers(topics.DIC.name) and \
                node.count_publishers(topics.IMPACTS.name):
            args.ready.touch()
        idle = dic and time.time() - dic[-1][0] > args.idle_s
        if idle or time.monotonic() - started > args.max_s:
            done.set_result(True)

    node.create_timer(0.2, check)
    executor = make_executor()
    executor.add_node(node)
    spin_until_done(executor, done, slice_s=0.2)
    args.out.write_text(json.dumps({"dic": dic, "impacts": impacts, "accel_impacts": accel}))
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
