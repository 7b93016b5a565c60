"""A camera-like source for bench_live: raw mono8 sensor_msgs/Image at a fixed rate, as a driver publishes.

    python bench/camera_peer.py RECORDING OUT.json --rate-hz 1000 [--topic camera/image_raw] \
        --ros-args -r __node:=camera_driver

Pre-loads every frame of RECORDING as an Image message (decoded once, so no file I/O or PNG decoding
while streaming), waits for a subscriber on the topic plus ``--settle-s``, then publishes frame k at
wall time start + k / rate_hz (absolute schedule: a late frame goes out at once, the schedule does not
slip), stamped with the frame's data time (t0_s + k / fps, like a driver's header stamp), best-effort
sensor QoS (qos_profile_sensor_data) like a camera driver's image_raw. Writes OUT.json: the wall time
(time.time(), s) at which each frame was handed to the publisher, by frame index, and each publish call over 5 ms
(``slow_publish_calls``: its frame, ms, the thread's CPU ms in it, its voluntary and involuntary context switches,
the GC ms in it).
"""

from __future__ import annotations

import argparse
import gc
import json
import resource
import sys
import time
from pathlib import Path

import rclpy
from daq_peer import shared_start
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from vibro_dic.frame_source_node import image_message
from vibro_io.recording import open_recording


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("out", type=Path, help="JSON file of publish wall times")
    parser.add_argument("--rate-hz", type=float, required=True)
    parser.add_argument("--topic", default="camera/image_raw")
    parser.add_argument("--time-origin-ns", type=int, default=0,
                        help="lab-clock origin of the stamps (ns since the epoch): stamp = origin + t0_s + k/fps")
    parser.add_argument("--settle-s", type=float, default=1.0, help="wait after the first subscriber matched")
    parser.add_argument("--wait-s", type=float, default=60.0, help="give up when no subscriber after this")
    parser.add_argument("--min-subscribers", type=int, default=1, help="wait until this many readers matched")
    parser.add_argument("--ready-file", type=Path, default=None,
                        help="touched once loaded and the readers matched (for a shared start)")
    parser.add_argument("--start-file", type=Path, default=None,
                        help="wait for this file, then take its content as the wall time (s) of camera time t0")
    parser.add_argument("--start-at-unix-s", type=float, default=None,
                        help="wall time (s) of frame 0, shared with daq_peer (default: --settle-s after a subscriber)")
    args = parser.parse_args(rclpy.utilities.remove_ros_args(argv)[1:])
    if args.rate_hz <= 0:
        print(f"camera_peer: --rate-hz must be > 0, got {args.rate_hz}", file=sys.stderr)
        return 2
    frames = [f for f in open_recording(args.recording).frames if f.ok]
    messages = [image_message(f, "camera", args.time_origin_ns) for f in frames]
    indices = [f.index for f in frames]
    del frames
    if any(m.encoding != "mono8" for m in messages):
        print("camera_peer: the recording's frames are not 8-bit (mono8 expected)", file=sys.stderr)
        return 2
    rclpy.init(args=argv)
    node = rclpy.create_node("camera_driver")
    pub = node.create_publisher(Image, args.topic, qos_profile_sensor_data)
    deadline = time.monotonic() + args.wait_s
    while pub.get_subscription_count() < max(args.min_subscribers, 1):
        if time.monotonic() > deadline:
            print(f"camera_peer: no subscriber on {args.topic} after {args.wait_s:g} s", file=sys.stderr)
            return 1
        time.sleep(0.05)
    start = shared_start(args)
    if start is None:
        time.sleep(args.settle_s)
        start = time.time() + 0.05
    published_at: list[float] = []
    slow: list[dict] = []  # publish calls over 5 ms: the driver itself stalled, and how
    gc_s = [0.0]  # time in Python's garbage collector since the last publish
    gc_began = [0.0]

    def gc_timer(phase: str, _info: dict) -> None:
        if phase == "start":
            gc_began[0] = time.perf_counter()
        else:
            gc_s[0] += time.perf_counter() - gc_began[0]

    gc.callbacks.append(gc_timer)
    period_s = 1.0 / args.rate_hz
    for k, msg in enumerate(messages):
        delay = start + k * period_s - time.time()
        if delay > 0:
            time.sleep(delay)
        published_at.append(time.time())
        cpu0, use0, gc_s[0] = time.thread_time(), resource.getrusage(resource.RUSAGE_THREAD), 0.0
        pub.publish(msg)
        took = time.time() - published_at[-1]
        if took > 0.005:
            use1 = resource.getrusage(resource.RUSAGE_THREAD)
            # busy (CPU ~ wall), waiting on something (voluntary switches) or descheduled (involuntary ones)
            slow.append({"frame": indices[k], "ms": round(1e3 * took, 2),
                         "thread_cpu_ms": round(1e3 * (time.thread_time() - cpu0), 2),
                         "voluntary_switches": use1.ru_nvcsw - use0.ru_nvcsw,
                         "involuntary_switches": use1.ru_nivcsw - use0.ru_nivcsw, "gc_ms": round(1e3 * gc_s[0], 2)})
    gc.callbacks.remove(gc_timer)
    time.sleep(0.5)  # let the last best-effort samples leave before the participant goes
    args.out.write_text(json.dumps({"rate_hz": args.rate_hz, "frame_index": indices,
                                    "published_at_s": published_at,
                                    "slow_publish_calls": slow}))
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
