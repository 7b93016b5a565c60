"""vibro replay of a live session's bag: camera-only (no accelerometers), its frames on the driver's topic."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from domains import private_domain

VIBRO = [sys.executable, "-m", "vibro_app.cli"]


def _vibro(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_DOMAIN_ID=private_domain(), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.run([*VIBRO, *args], capture_output=True, text=True, timeout=timeout, env=env)


def _bag_with_frames_on(source: Path, out: Path, image_topics: list[str]) -> Path:
    """``source``'s raw topics rewritten as a live session records them: its frames on each of ``image_topics``
    (a camera driver's topic instead of vibro/frames), its accelerometer blocks (if any) and metadata as they were."""
    from vibro_ros.bags import BagWriter, read_custom_data, read_messages

    w = BagWriter(out, custom_data=read_custom_data(source))
    for m in read_messages(source, {"vibro/frames", "vibro/accel"}):
        for topic in image_topics if m.topic == "vibro/frames" else ["/vibro/accel"]:
            w.add_topic(topic, m.msg_type)
            w.write(topic, m.timestamp_ns, m.data)
    w.close()
    return out


def test_a_video_only_live_sessions_bag_replays_from_its_camera_topic(tmp_path: Path) -> None:
    # A live graph is camera-only and records the camera where its driver publishes it (vibro/frames remapped).
    # Before: a replay read vibro/frames only ("no vibro/frames messages to replay"), and a replay of any bag
    # without accelerometers failed after 60 s (bag_source waited for trajectory_fitter on vibro/accel, which a
    # fitter without accelerometers never subscribes to).
    rec = tmp_path / "rec"
    made = _vibro("synth", "--no-accel", "--frames", "150", "--seed", "5", "--out", str(rec), "--no-progress")
    assert made.returncode == 0, made.stderr
    run = _vibro("graph", str(rec), "--bag", str(tmp_path / "bag"))
    assert run.returncode == 0, run.stdout + run.stderr
    live = _bag_with_frames_on(tmp_path / "bag", tmp_path / "live", ["/camera/image_raw"])
    replay = _vibro("replay", str(live), "--out", str(tmp_path / "re"))
    assert replay.returncode == 0, replay.stdout + replay.stderr
    assert "replay: frames from /camera/image_raw" in replay.stdout
    assert "frames in 150 / tracked 150 / lost 0" in replay.stdout, replay.stdout
    original = _vibro("results", str(tmp_path / "bag"), "--out", str(tmp_path / "orig"))
    assert original.returncode == 0, original.stderr
    a = json.loads((tmp_path / "orig" / "results.json").read_text())
    b = json.loads((tmp_path / "re" / "results.json").read_text())
    assert len(a["impacts"]) == len(b["impacts"]) > 0  # the same frames through the same code: the same numbers
    assert all(abs(x["cor"] - y["cor"]) < 1e-9 for x, y in zip(a["impacts"], b["impacts"]))


def test_replay_says_which_image_topic_when_it_cannot_tell(reference_run: dict, tmp_path: Path) -> None:
    two = _bag_with_frames_on(reference_run["bag"], tmp_path / "two", ["/cam_a/image_raw", "/cam_b/image_raw"])
    res = _vibro("replay", str(two), "--out", str(tmp_path / "re"))
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert "several image topics (/cam_a/image_raw, /cam_b/image_raw)" in res.stderr and "--frames-topic" in res.stderr
    res = _vibro("replay", str(two), "--out", str(tmp_path / "re2"), "--frames-topic", "/cam_c/image_raw")
    assert res.returncode == 2 and "no sensor_msgs/msg/Image topic /cam_c/image_raw recorded" in res.stderr
