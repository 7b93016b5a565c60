"""A DAQ-like source for bench_live and the live accelerometer tests: a recording's accel.csv as live AccelBlocks.

    python bench/daq_peer.py RECORDING OUT.json [--speed 1] [--block-samples 1000] [--time-origin-ns NS] \
        [--start-at-unix-s S] [--drop-blocks 5,6] --ros-args -r __node:=daq_driver

Publishes what docs/live.md asks of a DAQ driver (*Live accelerometers*): vibro_msgs/AccelBlock on vibro/accel,
reliable, transient local, depth 100; a fixed number of samples per block (``--block-samples``; the last partial block
is not sent, as a driver sends only full buffers); ``block_index`` from 0, ``first_sample_index`` the sample count,
``t_start_s`` the DAQ time of the block's first sample (accel.csv's time column), m/s^2 (+ up); ``header.stamp`` the
lab-clock time of that sample: origin + DAQ time - the DAQ's clock offset (from the synthetic recording's truth
file beside it, ``clock_offset_s``, or ``--clock-offset-s``), as a driver reading a synchronised lab clock stamps.

Real time: a block goes out when its last sample has been taken, at wall time start + (t_end - t0_s) / speed on
the camera's clock (``--start-at-unix-s``: the wall time of camera time t0_s, shared with camera_peer so both
peers run on one schedule; default: 0.5 s after a subscriber matched); ``--speed`` as the camera's rate over its
fps. ``--drop-blocks``: indices not sent (a DAQ's lost blocks). Writes OUT.json: per block sent its index and the
wall time it was published.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from vibro_io.recording import open_recording
from vibro_io.rig import load_rig
from vibro_msgs.msg import AccelBlock
from vibro_ros.node_support import stamp_from_seconds

#: what docs/live.md asks of a driver: reliable, transient local (the nodes' own reader matches it at once), a second
#: of 20 ms blocks
DRIVER_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


def blocks(recording: Path, block_n: int, origin_ns: int, clock_offset_s: float) -> list[AccelBlock]:
    """The full blocks of ``recording``'s accelerometer file as AccelBlock messages, stamped on the lab clock."""
    data = open_recording(recording).load_accel()
    if data is None:
        raise SystemExit(f"daq_peer: {recording} has no accelerometer file")
    out = []
    for i, s in enumerate(range(0, len(data) - block_n + 1, block_n)):
        msg = AccelBlock(block_index=i, first_sample_index=s, sample_rate_hz=float(data.sample_rate_hz),
                         t_start_s=float(data.t_s[s]))
        msg.upper_ms2 = np.asarray(data.upper_ms2[s:s + block_n], float).tolist()
        msg.lower_ms2 = np.asarray(data.lower_ms2[s:s + block_n], float).tolist()
        msg.header.frame_id = "daq"
        stamp_from_seconds(msg.header, msg.t_start_s - clock_offset_s, origin_ns)
        out.append(msg)
    return out


def truth_offset_s(recording: Path) -> float:
    """The synthetic recording's DAQ clock offset (truth file beside it), else 0."""
    truth = recording.parent / f"{recording.name}.truth.json"
    if truth.is_file():
        return float(json.loads(truth.read_text()).get("clock_offset_s", 0.0))
    return 0.0


def wait_acknowledged(pub, timeout_s: float = 30.0) -> bool:
    """Block until every reliable reader of ``pub`` has acknowledged all it was sent (at most ``timeout_s``):
    a participant that leaves earlier takes its unsent samples with it, and a loaded reader can be seconds
    behind. True when acknowledged."""
    from rclpy.duration import Duration

    return bool(pub.wait_for_all_acked(Duration(nanoseconds=int(timeout_s * 1e9))))


def wait_for_subscribers(pub, count: int, timeout_s: float) -> bool:
    """Block until ``pub`` has at least ``count`` matched readers (at most ``timeout_s``); True when it has: a
    volatile reader matched after the stream began would start mid-stream."""
    deadline = time.monotonic() + timeout_s
    while pub.get_subscription_count() < count:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def shared_start(args) -> float | None:
    """The wall time of camera time t0: ``--start-at-unix-s``, else (with ``--start-file``) the content of that file
    once it exists, after touching ``--ready-file``; None when neither is given."""
    if args.ready_file is not None:
        args.ready_file.touch()
    if args.start_at_unix_s is not None:
        return float(args.start_at_unix_s)
    if args.start_file is None:
        return None
    deadline = time.monotonic() + args.wait_s
    while not args.start_file.exists():
        if time.monotonic() > deadline:
            raise SystemExit(f"no start file {args.start_file} after {args.wait_s:g} s")
        time.sleep(0.01)
    time.sleep(0.01)  # written whole (the writer renames it into place)
    return float(args.start_file.read_text())


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("out", type=Path, help="JSON file of publish wall times")
    parser.add_argument("--speed", type=float, default=1.0, help="multiple of real time (camera rate / fps)")
    parser.add_argument("--block-samples", type=int, default=1000, help="samples per block (1000 = 20 ms at 50 kHz)")
    parser.add_argument("--topic", default="vibro/accel")
    parser.add_argument("--time-origin-ns", type=int, default=0, help="lab-clock origin of the camera time (ns)")
    parser.add_argument("--clock-offset-s", type=float, default=None,
                        help="DAQ time - camera time (s); default: the truth file's clock_offset_s, else 0")
    parser.add_argument("--start-at-unix-s", type=float, default=None,
                        help="wall time (s) of camera time t0_s; default 0.5 s after a subscriber matched")
    parser.add_argument("--drop-blocks", default="", help="block indices not sent, comma-separated")
    parser.add_argument("--wait-s", type=float, default=60.0, help="give up when no subscriber after this")
    parser.add_argument("--min-subscribers", type=int, default=1, help="wait until this many readers matched")
    parser.add_argument("--ready-file", type=Path, default=None,
                        help="touched once loaded and the readers matched (for a shared start)")
    parser.add_argument("--start-file", type=Path, default=None,
                        help="wait for this file, then take its content as the wall time (s) of camera time t0")
    args = parser.parse_args(rclpy.utilities.remove_ros_args(argv)[1:])
    if args.speed <= 0 or args.block_samples <= 0:
        print("daq_peer: --speed and --block-samples must be > 0", file=sys.stderr)
        return 2
    offset = truth_offset_s(args.recording) if args.clock_offset_s is None else args.clock_offset_s
    messages = blocks(args.recording, args.block_samples, args.time_origin_ns, offset)
    drop = {int(x) for x in args.drop_blocks.split(",") if x.strip()}
    t0 = load_rig(args.recording / "rig.yaml").camera.t0_s
    rclpy.init(args=argv)
    node = rclpy.create_node("daq_driver")
    pub = node.create_publisher(AccelBlock, args.topic, DRIVER_QOS)
    if not wait_for_subscribers(pub, max(args.min_subscribers, 1), args.wait_s):
        print(f"daq_peer: no subscriber on {args.topic} after {args.wait_s:g} s", file=sys.stderr)
        return 1
    start = shared_start(args) or time.time() + 0.5
    sent, at = [], []
    for msg in messages:
        t_end_cam = msg.t_start_s + len(msg.upper_ms2) / msg.sample_rate_hz - offset
        delay = start + (t_end_cam - t0) / args.speed - time.time()
        if delay > 0:
            time.sleep(delay)
        if msg.block_index in drop:
            continue
        pub.publish(msg)
        sent.append(int(msg.block_index))
        at.append(time.time())
    if not wait_acknowledged(pub):
        print(f"daq_peer: the readers of {args.topic} did not acknowledge every block within 30 s", file=sys.stderr)
    args.out.write_text(json.dumps({"block_index": sent, "published_at_s": at, "clock_offset_s": offset,
                                    "block_samples": args.block_samples,
                                    "sample_rate_hz": messages[0].sample_rate_hz if messages else None}))
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
