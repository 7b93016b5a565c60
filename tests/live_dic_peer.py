"""A stand-in for a live dic_tracker in the live accelerometer tests: a recording's DIC rows as DicFrames in real time.

    python tests/live_dic_peer.py RECORDING --start-at-unix-s S [--time-origin-ns NS] --ros-args -r __node:=dic_tracker

Tracks RECORDING offline first (vibro_dic.tracker.track_recording, the tracker's core), then publishes frame k's
DicFrame on vibro/dic (latched history, as the tracker does) at wall time S + (t_k - t0_s) + one frame (when a
live tracker has its result), stamped on the lab clock of the origin. Exits 0 after the last frame.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import rclpy

from vibro_dic.tracker import track_recording
from vibro_io.recording import open_recording
from vibro_msgs.msg import DicFrame
from vibro_ros import topics
from vibro_ros.convert import frame_track_to_message
from vibro_ros.node_support import history_qos


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("--start-at-unix-s", type=float, required=True)
    parser.add_argument("--time-origin-ns", type=int, default=0)
    args = parser.parse_args(rclpy.utilities.remove_ros_args(sys.argv)[1:])
    rec = open_recording(args.recording)
    rows = list(track_recording(rec))
    cam = rec.rig.camera
    rclpy.init(args=sys.argv)
    node = rclpy.create_node("dic_tracker")
    pub = node.create_publisher(DicFrame, topics.DIC.name, history_qos(len(rows) + 10))
    for row in rows:
        delay = args.start_at_unix_s + (row.t_s - cam.t0_s) + 1.0 / cam.fps - time.time()
        if delay > 0:
            time.sleep(delay)
        pub.publish(frame_track_to_message(row, (1, 1), "", 0, "", args.time_origin_ns))
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
