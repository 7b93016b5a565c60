"""StreamStatus rate: a source may call StatusPublisher.publish on every tick (frame_source: 100 Hz), but every node
of the graph reads vibro/status, so progress goes out at most every min_interval_s and an unchanged status not at
all; nothing a reader needs is lost: the newest progress goes out by the next repeat, a finished status at once.

Real rclpy publisher and subscriber in one process, on a private ROS domain."""

from __future__ import annotations

import time

import pytest


@pytest.fixture
def node_pair(ros_domain: str):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from vibro_msgs.msg import StreamStatus
    from vibro_ros import topics
    from vibro_ros.adaptive_qos import results_subscription
    from vibro_ros.node_support import StatusPublisher

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    pub_node = rclpy.create_node("status_source", context=ctx)
    sub_node = rclpy.create_node("status_reader", context=ctx)
    got: list[tuple[float, int, bool]] = []
    results_subscription(sub_node, StreamStatus, topics.STATUS.name,
                         lambda m: got.append((time.monotonic(), int(m.items_sent), bool(m.finished))))
    status = StatusPublisher(pub_node, "frames", min_interval_s=0.1)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(pub_node)
    ex.add_node(sub_node)

    def spin_for(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.005)

    deadline = time.monotonic() + 10
    while status._pub.get_subscription_count() < 1:  # matched before anything is published
        assert time.monotonic() < deadline, "the reader never matched"
        spin_for(0.05)
    try:
        yield status, got, spin_for
    finally:
        ex.shutdown()
        pub_node.destroy_node()
        sub_node.destroy_node()
        rclpy.shutdown(context=ctx)


def test_progress_is_rate_limited_unchanged_not_resent_and_the_end_arrives(node_pair) -> None:
    status, got, spin_for = node_pair
    # 1 s of a 200 Hz source: 200 calls with a new count each
    start = time.monotonic()
    sent = 0
    while time.monotonic() - start < 1.0:
        sent += 1
        status.publish(sent, 0, False)
        spin_for(0.005)
    for _ in range(50):  # a source waiting for acknowledgements calls again with the same count
        status.publish(sent, 0, False)
        spin_for(0.002)
    elapsed = time.monotonic() - start
    progress = [g for g in got if not g[2]]
    # at most one per 0.1 s (+1 for the first call): ~11, not the ~200 calls
    assert 3 <= len(progress) <= elapsed / 0.1 + 2, len(progress)
    counts = [g[1] for g in progress]
    assert counts == sorted(set(counts))  # increasing: no value sent twice
    # the newest count reaches the reader without another call (the 1 s repeat) ...
    spin_for(1.3)
    assert [g[1] for g in got if not g[2]][-1] == sent
    # ... and the end of the stream at once, even right after a progress update
    status.publish(sent + 1, 0, False)
    t_end = time.monotonic()
    status.publish(sent + 2, 0, True)
    spin_for(0.3)
    finals = [g for g in got if g[2]]
    assert finals and finals[0][1] == sent + 2 and finals[0][0] - t_end < 0.3
