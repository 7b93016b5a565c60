"""A sink (the recorder) ends when its declared writers have come and gone; a writer whose data arrives but
which this node's ROS graph view never lists (seen with two graphs on one domain under load: the recorder
waited 200 s for impact_detector until the run's timeout) is taken as gone once all its streams ended."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

#: publishes impact_detector's end-of-stream status from a node of ANOTHER name, so the graph never lists a
#: node "impact_detector": what the recorder saw when its graph view missed the real one
ANNOUNCER = """
import sys, time, rclpy
from vibro_msgs.msg import StreamStatus
from vibro_ros.node_support import RESULTS_QOS
rclpy.init(args=sys.argv)
node = rclpy.create_node("status_announcer")
pub = node.create_publisher(StreamStatus, "vibro/status", RESULTS_QOS)
msg = StreamStatus(stream="accel_impacts", items_sent=3, items_lost=0, finished=True)
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    pub.publish(msg)
    rclpy.spin_once(node, timeout_sec=0.5)
"""


def _recorder_and_announcer(bag: Path, namespace: str, script: str, seconds: int):
    """A recorder declaring impact_detector as its writer, and the status announcer, in ``namespace``."""
    ns = ["-r", f"__ns:={namespace}"]
    recorder = subprocess.Popen([sys.executable, "-m", "vibro_bringup.recorder_node", "--ros-args", *ns,
                                 "-p", f"bag:={bag}", "-p", "writers:=[impact_detector]"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    announcer = subprocess.Popen([sys.executable, "-c", script, str(seconds), "--ros-args", *ns],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return recorder, announcer


def test_recorder_ends_when_an_unlisted_writers_streams_have_ended(tmp_path: Path, ros_domain: str) -> None:
    recorder, announcer = _recorder_and_announcer(tmp_path / "bag", "/lab7", ANNOUNCER, 20)
    try:
        t0 = time.monotonic()
        out, err = recorder.communicate(timeout=60)
        elapsed = time.monotonic() - t0
    finally:
        for p in (recorder, announcer):
            if p.poll() is None:
                p.kill()
            p.communicate()
    assert recorder.returncode == 0, err
    assert "impact_detector never appeared in this node's ROS graph view" in err, err
    assert "accel_impacts" in err and "Traceback" not in err
    assert elapsed < 20, elapsed  # ended on the status, not on the announcer leaving (it stays up 20 s)


def test_recorder_keeps_waiting_while_a_writers_streams_have_not_ended(tmp_path: Path, ros_domain: str) -> None:
    # the same, but the status is not final: the recorder must not end on it
    script = ANNOUNCER.replace("finished=True", "finished=False")
    recorder, announcer = _recorder_and_announcer(tmp_path / "bag", "/lab8", script, 8)
    try:
        announcer.communicate(timeout=60)
        time.sleep(2.0)
        assert recorder.poll() is None, recorder.communicate()[1]
    finally:
        if recorder.poll() is None:
            recorder.send_signal(2)
        recorder.communicate(timeout=30)
