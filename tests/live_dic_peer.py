"""A stand-in for a live dic_tracker in the live accelerometer tests: a recording's DIC rows as DicFrames in real time.

    python tests/live_dic_peer.py RECORDING (--start-at-unix-s S | --ready-file R --start-file F) \
        [--time-origin-ns NS] --ros-args -r __node:=dic_tracker

Tracks RECORDING offline first (vibro_dic.tracker.track_recording, the tracker's core), then publishes frame k's
DicFrame on vibro/dic (latched history, as the tracker does) at wall time S + (t_k - t0_s) + one frame (when a
live tracker has its result), stamped on the lab clock of the origin. Exits 0 once its readers acknowledged the
last frame. With ``--ready-file`` and ``--start-file`` it touches the first once tracked and ``--min-subscribers``
readers matched, then takes S from the second (bench/daq_peer.py's shared start: a loaded machine's slow start
cannot push the stream past S).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import rclpy

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from daq_peer import shared_start, wait_acknowledged, wait_for_subscribers  # noqa: E402

from vibro_dic.tracker import track_recording
from vibro_io.recording import open_recording
from vibro_msgs.msg import DicFrame
from vibro_ros import topics
from vibro_ros.convert import frame_track_to_message
from vibro_ros.node_support import history_qos


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("--start-at-unix-s", type=float, default=None)
    parser.add_argument("--ready-file", type=Path, default=None)
    parser.add_argument("--start-file", type=Path, default=None)
    parser.add_argument("--wait-s", type=float, default=60.0, help="give up when no start file after this")
    parser.add_argument("--time-origin-ns", type=int, default=0)
    parser.add_argument("--min-subscribers", type=int, default=1,
                        help="readers of vibro/dic matched before the ready file is touched")
    args = parser.parse_args(rclpy.utilities.remove_ros_args(sys.argv)[1:])
    rec = open_recording(args.recording)
    rows = list(track_recording(rec))
    cam = rec.rig.camera
    rclpy.init(args=sys.argv)
    node = rclpy.create_node("dic_tracker")
    pub = node.create_publisher(DicFrame, topics.DIC.name, history_qos(len(rows) + 10))
    # ready only once the readers have matched: a volatile reader matched after the stream began would start
    # mid-stream (a loaded machine's discovery took longer than the whole 0.6 s stream: the fitter got no frame)
    if not wait_for_subscribers(pub, args.min_subscribers, args.wait_s):
        print(f"live_dic_peer: {pub.get_subscription_count()} of {args.min_subscribers} readers of vibro/dic "
              f"after {args.wait_s:g} s", file=sys.stderr)
        return 1
    start = shared_start(args)
    if start is None:
        parser.error("give --start-at-unix-s, or --ready-file and --start-file")
    for row in rows:
        delay = start + (row.t_s - cam.t0_s) + 1.0 / cam.fps - time.time()
        if delay > 0:
            time.sleep(delay)
        pub.publish(frame_track_to_message(row, (1, 1), "", 0, "", args.time_origin_ns))
    # a loaded reader can be seconds behind: the frames it has not yet acknowledged leave with this participant
    if not wait_acknowledged(pub, 60.0):
        print("live_dic_peer: vibro/dic not acknowledged by every reader within 60 s", file=sys.stderr)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
