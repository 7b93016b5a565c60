"""A live dic_tracker is ready before the camera starts, and a session whose first images were dropped still
begins at its reference frame (issue #28, start-up). Driven in-process: the node's image callback called
directly with the Image messages a driver would send (no DDS); its results are read where it holds them
until its declared reader (here one that never comes) has matched."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

ORIGIN_NS = 1_764_000_000_000_000_000


def _node(rec: Path, *params: str):
    import rclpy

    from vibro_dic.dic_tracker_node import DicTrackerNode

    rclpy.init(args=["--ros-args", "-p", f"rig_file:={rec / 'rig.yaml'}", "-p", "readers:=[nobody_yet]",
                     "-p", f"time_origin_unix_ns:={ORIGIN_NS}", *params])
    return DicTrackerNode()


def _images(rec: Path) -> dict[int, object]:
    from vibro_dic.frame_source_node import image_message
    from vibro_io.recording import open_recording

    return {f.index: image_message(f, "camera", ORIGIN_NS) for f in open_recording(rec).frames if f.ok}


def _camera_matched(close_rclpy) -> tuple[object, float]:
    """A camera driver's image publisher (sensor QoS) on vibro/frames, once the tracker's reader has matched it, and
    a deadline (monotonic s) 10 s from its start for what the test waits for next."""
    import time

    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Image

    camera = rclpy.create_node("camera_driver")
    close_rclpy.append(camera)
    pub = camera.create_publisher(Image, "vibro/frames", qos_profile_sensor_data)
    deadline = time.monotonic() + 10
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.02)
    return pub, deadline


def test_ready_before_the_first_image_and_the_dropped_first_images_answered(tiny_recording: Path,
                                                                            close_rclpy, ros_domain) -> None:
    node = _node(tiny_recording, "-p", "live_camera:=true", "-p",
                 f"reference_image:={tiny_recording / 'frames' / '000000.png'}")
    close_rclpy.append(node)
    # built from the reference file at start and every per-image path run once: nothing is left to set up when the
    # first image arrives; not ready while its declared reader of vibro/dic has not matched
    assert node.tracker is not None and node.health.values["ready"].startswith("false: tracker built and warm")
    # the warm-up tracked the reference as frames 0-3 and then forgot them: no motion history carries over
    assert not node.tracker.ball.history and not node.tracker.structure.history and not node._held
    node.gate.open = True  # the reader matched (what the gate's poll finds over DDS)
    node._release()
    assert node.health.values["ready"] == "true"
    node.gate.open = False  # hold the results again, to read them below
    images = _images(tiny_recording)
    node._on_image(images[2])  # frames 0 and 1 never arrived: the camera's first images were dropped
    node._on_image(images[3])
    rows = {int(m.frame_index): m for m in node._held}
    assert sorted(rows) == [0, 1, 2, 3]
    for k in (0, 1):
        assert rows[k].lost and rows[k].status.startswith("before the first image received"), rows[k].status
        assert rows[k].reference_frame_index == 0
    # the fixture's ball moves down 2 whole px per frame at 0.05 mm/px: -0.1 mm per frame, measured against
    # frame 0 from the file (interpolation error of a noise-free pattern: far under 0.02 px = 0.001 mm)
    for k in (2, 3):
        assert not rows[k].lost and abs(rows[k].ball_mm - (-0.1 * k)) < 1e-3, rows[k]
        assert abs(rows[k].structure_mm) < 1e-3


def test_without_a_reference_file_ready_says_the_first_image_becomes_it(tiny_recording: Path, close_rclpy,
                                                                       ros_domain) -> None:
    node = _node(tiny_recording, "-p", "live_camera:=true")
    close_rclpy.append(node)
    assert node.tracker is None and node.health.values["ready"].startswith("false: no reference_image")
    node._on_image(_images(tiny_recording)[1])
    (row,) = node._held  # the first image is the reference: the stream begins there, nothing before it
    assert row.frame_index == 1 and row.reference_frame_index == 1 and not row.lost
    assert math.isclose(row.ball_mm, 0.0, abs_tol=1e-6)  # the reference itself: 0 to the solver's tolerance


def test_from_a_recording_no_ready_flag_and_no_leading_slots(tiny_recording: Path, close_rclpy,
                                                             ros_domain) -> None:
    """File mode: a tracker restarted mid-run gets its first image late; the earlier slots were answered by the
    tracker before it, so they are not answered again (readers would see frame numbers go back)."""
    node = _node(tiny_recording, "-p", f"reference_image:={tiny_recording / 'frames' / '000000.png'}")
    close_rclpy.append(node)
    assert "ready" not in node.health.values
    node._on_image(_images(tiny_recording)[3])
    assert [int(m.frame_index) for m in node._held] == [3]


def _pin_work_per_frame(node, seconds: float) -> None:
    """The catch-up policy's measure of the tracker's own work per frame, fixed (whatever this machine's load)."""
    node.catch_up_policy.cost_s = seconds
    node.catch_up_policy.worked = lambda _seconds: None


@pytest.mark.parametrize("catch_up", ["0", "5000"])
def test_images_waiting_behind_the_one_handed_over_are_tracked_within_the_bound_and_skipped_beyond(
        tiny_recording: Path, close_rclpy, ros_domain, catch_up: str) -> None:
    """Four images queued behind a stalled tracker whose work is 0.1 ms a frame: with catch_up_ms 0 the newest is
    tracked across the gap and the three older ones are skipped; with a catch-up time that tracker could work off
    thousands of frames in (5 s: the deadline is wall time, which a loaded machine stretches) all four are
    tracked, oldest first."""
    import time

    from sensor_msgs.msg import Image

    from vibro_dic.catch_up import SKIPPED

    extra = ["-p", f"catch_up_ms:={float(catch_up)}"]
    node = _node(tiny_recording, "-p", "live_camera:=true", "-p",
                 f"reference_image:={tiny_recording / 'frames' / '000000.png'}", *extra)
    close_rclpy.append(node)
    assert node.catch_up_policy.catch_up_s == 1e-3 * float(catch_up)
    _pin_work_per_frame(node, 1e-4)
    pub, deadline = _camera_matched(close_rclpy)
    images = _images(tiny_recording)
    for k in (0, 1, 2, 3):  # a stalled tracker: four images queued before it looks again
        pub.publish(images[k])
    got = None
    while got is None and time.monotonic() < deadline:
        time.sleep(0.05)
        got = node._image_sub.handle.take_message(Image, False)  # what the executor hands the callback: frame 0
    assert got is not None
    time.sleep(1.0)  # frames 1-3 delivered into the reader's queue behind it
    node._on_image(got[0])
    while node._backlog:  # what the resume timer does after each work slice (20 ms; a loaded machine needs several)
        node._work_backlog()
    rows = {int(m.frame_index): m for m in node._held}
    assert sorted(rows) == [0, 1, 2, 3]
    if catch_up == "0":
        for k in (0, 1, 2):
            assert rows[k].lost and rows[k].status == SKIPPED
        assert node.health.counters["skipped"] == 3 and node.health.values["catch_up_last"] == "frames 0..2"
    else:
        assert not any(rows[k].lost for k in (0, 1, 2)) and "skipped" not in node.health.counters
    assert not rows[3].lost and abs(rows[3].ball_mm - (-0.3)) < 1e-3  # frame 3's displacement, either way


@pytest.mark.parametrize("depth", [None, 5])
def test_a_stalled_trackers_reader_keeps_image_queue_depth_images(tiny_recording: Path, close_rclpy, ros_domain,
                                                                  depth: int | None) -> None:
    """20 images arrive while the tracker is stalled (its executor not taking them): its best-effort reader keeps
    the last ``image_queue_depth`` of them. The default (50) keeps all 20, which are tracked; the sensor QoS's usual
    depth 5 keeps frames 15-19 only, and 0-14 are answered as lost, never received (no image, so not 'skipped')."""
    import time

    from sensor_msgs.msg import Image

    from vibro_dic.catch_up import SKIPPED
    from vibro_dic.frame_source_node import image_message
    from vibro_io.frames import Frame
    from vibro_io.recording import open_recording

    # the catch-up policy (its own tests: test_catch_up.py) never passes an image over, however slowly a loaded
    # machine tracks the 20: its work per frame pinned at 0.1 ms, and its deadline (wall time) far beyond the test's
    extra = ["-p", f"image_queue_depth:={depth}"] if depth else []
    node = _node(tiny_recording, "-p", "live_camera:=true", "-p",
                 f"reference_image:={tiny_recording / 'frames' / '000000.png'}", "-p", "catch_up_ms:=5000.0", *extra)
    close_rclpy.append(node)
    _pin_work_per_frame(node, 1e-4)
    pub, deadline = _camera_matched(close_rclpy)
    rec = open_recording(tiny_recording)
    still = next(iter(rec.frames)).image  # the scene of frame 0 in every image: each tracks to 0 mm
    n = 20
    for k in range(n):
        pub.publish(image_message(Frame(index=k, t_s=rec.rig.camera.frame_time_s(k), image=still, source="test"),
                                  "camera", ORIGIN_NS))
    time.sleep(1.0)  # delivered into the reader's queue; the tracker has not looked
    got = node._image_sub.handle.take_message(Image, False)
    assert got is not None
    node._on_image(got[0])
    while node._backlog:  # what the resume timer does after each work slice (20 ms)
        node._work_backlog()
    rows = {int(m.frame_index): m for m in node._held}
    assert sorted(rows) == list(range(n))
    kept = n if depth is None else depth
    for k in range(n - kept, n):
        assert not rows[k].lost and abs(rows[k].ball_mm) < 1e-3, k
    for k in range(n - kept):
        assert rows[k].lost and rows[k].status != SKIPPED and "image" in rows[k].status, (k, rows[k].status)
    assert "skipped" not in node.health.counters


@pytest.mark.parametrize("released", [False, True])
@pytest.mark.parametrize("live", [True, False])
def test_unreadable_images_are_answered_lost_naming_the_field(tiny_recording: Path, close_rclpy, ros_domain,
                                                              live: bool, released: bool) -> None:
    """Images arrive serialized (a raw subscription). One cut short, one of another encoding, one whose bytes end
    before its stamp: each slot is answered exactly once, in order, the first two lost with the field that could
    not be read, the third lost as never received once a later image comes (it has no readable stamp, so no slot);
    the good images around them are tracked. Live (camera) and from a recording alike; held as messages until the
    readers match, or (``released``) published as the CDR bytes the node writes itself."""
    import copy

    from rclpy.serialization import deserialize_message, serialize_message

    from vibro_msgs.msg import DicFrame

    node = _node(tiny_recording, "-p", f"live_camera:={str(live).lower()}", "-p",
                 f"reference_image:={tiny_recording / 'frames' / '000000.png'}")
    close_rclpy.append(node)
    node.gate.open = released  # else results held, to read them below
    sent = []
    if released:
        assert node._raw_dic  # the node's start check: its bytes read back as rclpy's
        node.pub = type("Capture", (), {"publish": lambda _self, m: sent.append(m)})()
    images = _images(tiny_recording)
    other = copy.deepcopy(images[2])
    other.encoding = "bgr8"
    feed = [serialize_message(images[0]), serialize_message(images[1])[:-10], serialize_message(other),
            serialize_message(images[3])[:11], serialize_message(images[4])]
    for raw in feed:
        node._on_image(raw)
    if released:
        assert not node._held and all(isinstance(m, bytes) for m in sent)
    msgs = [deserialize_message(m, DicFrame) for m in sent] if released else node._held
    rows = [(int(m.frame_index), bool(m.lost), m.status) for m in msgs]
    assert [k for k, _, _ in rows] == [0, 1, 2, 3, 4]
    assert not rows[0][1] and not rows[4][1]
    assert rows[1][1] and rows[1][2].startswith("image data: ") and "truncated" in rows[1][2], rows[1]
    assert rows[2][1] and rows[2][2] == "image encoding 'bgr8' not supported (mono8 or mono16)", rows[2]
    assert rows[3][1] and rows[3][2].startswith("no image received"), rows[3]
    assert node.health.counters["unreadable"] == 1 and node.lost == 3 and node.published == 5
    assert all(m.reference_frame_index == 0 and m.header.frame_id == "camera" for m in msgs)
    assert abs(msgs[4].ball_mm - (-0.4)) < 1e-3  # frame 4's displacement (the fixture: -0.1 mm per frame)
