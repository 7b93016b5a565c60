"""dic_tracker's message handling per frame, in one process: the Image in, the DicFrame out, without the DIC.

    scripts/py bench/bench_tracker_io.py [--n 3000] [--rounds 5] [--readers 2]

What the live tracker does with each frame besides tracking it, each step timed alone (CPU time of this thread,
median of ``--rounds`` rounds of ``--n`` frames, rounds of the steps interleaved):

- ``image_deserialize``: the serialized Image (a 160 x 480 mono8 camera frame, as a raw subscription or the
  executor's take has it) deserialized into a sensor_msgs/Image, its pixels made an array
  (``dic_tracker_node.image_array``) and converted to float32 for the DIC: the path before issue 41;
- ``image_raw_decode``: the same bytes read in place (:func:`vibro_dic.raw_image.decode_image`) and their pixels
  copied into one preallocated float32 buffer (``np.copyto``): the path since;
- ``dicframe_build``: a DicFrame built (``dic_tracker_node.dic_message``);
- ``dicframe_publish_msg``: that message published (rclpy converts it to C and serializes it);
- ``dicframe_refill``: one DicFrame instance kept and its fields set per frame instead (rclpy converts a message when
  it is published, so the same instance may be published again);
- ``dicframe_encode``: the same DicFrame's CDR bytes written by :class:`vibro_dic.dic_frame_cdr.DicFrameEncoder`;
- ``dicframe_publish_raw``: those bytes published (``publish(bytes)``: no conversion, no serialization).

The publishers have ``--readers`` matched readers in other nodes of this process (never spun: what DDS does for a
reader is part of publish). In the graph the readers are other processes (shared-memory transport), so only the
differences between paths carry over, not the absolute publish cost. Results: stdout and
bench/results/tracker_io.json.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=3000, help="frames per round")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--readers", type=int, default=2, help="matched DicFrame readers (other nodes, not spun)")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "tracker_io.json")
    args = parser.parse_args()

    import rclpy
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Image

    from vibro_dic.dic_frame_cdr import DicFrameEncoder
    from vibro_dic.dic_tracker_node import dic_message, image_array
    from vibro_dic.raw_image import decode_image
    from vibro_io.dictrack import FrameTrack
    from vibro_msgs.msg import DicFrame
    from vibro_ros.node_support import history_qos

    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, size=(480, 160), dtype=np.uint8)
    msg = Image(height=img.shape[0], width=img.shape[1], encoding="mono8", step=img.shape[1], data=img.tobytes())
    msg.header.frame_id = "camera"
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_764_000_000, 123_456_789
    raw = serialize_message(msg)
    buf = np.empty(img.shape, dtype=np.float32)
    origin = 1_764_000_000_000_000_000
    row = FrameTrack(frame=1234, t_s=1.234, ball_mm=-0.123456, structure_mm=0.0123, ball_valid=40, structure_valid=90,
                     ball_zncc=0.99871, structure_zncc=0.9991, lost=False, ball_rot_rad=1.2e-3, ball_rot_std_rad=3e-5)
    mesh = (45, 97)
    enc = DicFrameEncoder(mesh, origin_ns=origin)
    assert len(enc.encode(row, "", 0, "run")) == len(serialize_message(dic_message(row, mesh, "", 0, "run", origin)))

    rclpy.init()
    node = rclpy.create_node("bench_tracker_io")
    qos = history_qos(1000)
    pub = node.create_publisher(DicFrame, "bench/dic", qos)
    readers = []
    for i in range(args.readers):
        r = rclpy.create_node(f"bench_reader_{i}")
        r.create_subscription(DicFrame, "bench/dic", lambda _m: None, qos)
        readers.append(r)
    deadline = time.monotonic() + 10
    while pub.get_subscription_count() < args.readers and time.monotonic() < deadline:
        time.sleep(0.05)

    built = dic_message(row, mesh, "", 0, "run", origin)
    encoded = enc.encode(row, "", 0, "run")
    kept = dic_message(row, mesh, "", 0, "run", origin)

    def refill() -> None:  # the fields that change per frame, set on the kept instance
        kept.frame_index, kept.t_s, kept.ball_mm, kept.structure_mm = row.frame, row.t_s, row.ball_mm, row.structure_mm
        kept.ball_valid_points, kept.structure_valid_points = row.ball_valid, row.structure_valid
        kept.ball_mean_zncc, kept.structure_mean_zncc, kept.lost = row.ball_zncc, row.structure_zncc, row.lost
        kept.status, kept.ball_rot_rad, kept.ball_rot_std_rad = "", row.ball_rot_rad, row.ball_rot_std_rad
        kept.header.stamp.sec, kept.header.stamp.nanosec = divmod(origin + round(row.t_s * 1e9), 1_000_000_000)

    steps = {
        "image_deserialize": lambda: image_array(deserialize_message(raw, Image)).astype(np.float32),
        "image_raw_decode": lambda: np.copyto(buf, decode_image(raw).pixels()),
        "dicframe_build": lambda: dic_message(row, mesh, "", 0, "run", origin),
        "dicframe_publish_msg": lambda: pub.publish(built),
        "dicframe_refill": refill,
        "dicframe_encode": lambda: enc.encode(row, "", 0, "run"),
        "dicframe_publish_raw": lambda: pub.publish(encoded),
    }
    times: dict[str, list[float]] = {k: [] for k in steps}
    for _ in range(args.rounds):
        for name, step in steps.items():
            for _ in range(50):
                step()
            t0 = time.thread_time()
            for _ in range(args.n):
                step()
            times[name].append(1e3 * (time.thread_time() - t0) / args.n)
    for r in readers:
        r.destroy_node()
    node.destroy_node()
    rclpy.shutdown()

    med = {k: float(np.median(v)) for k, v in times.items()}
    result = {"command": " ".join(sys.argv), "n": args.n, "rounds": args.rounds, "readers": args.readers,
              "image": f"{img.shape[1]}x{img.shape[0]} mono8, {len(raw)} bytes serialized",
              "ms_per_frame_median": med, "ms_per_frame_rounds": times,
              "before_ms": med["image_deserialize"] + med["dicframe_build"] + med["dicframe_publish_msg"],
              "after_ms": med["image_raw_decode"] + med["dicframe_encode"] + med["dicframe_publish_raw"]}
    for k, v in med.items():
        spread = f"{min(times[k]):.4f}-{max(times[k]):.4f}"
        print(f"{k:22s} {v:7.4f} ms/frame (rounds {spread})")
    print(f"image in + DicFrame out: {result['before_ms']:.4f} ms before, {result['after_ms']:.4f} ms after "
          f"({args.readers} readers in this process)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    return 0 if all(math.isfinite(v) for v in med.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
