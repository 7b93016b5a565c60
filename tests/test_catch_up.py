"""The live tracker's catch-up policy (vibro_dic.catch_up): a backlog within its bound is tracked oldest first (a
short stall costs no image), beyond it the oldest images are skipped and reported (a long stall is one block, the
lag stays bounded); with no bound it jumps to the newest image at once; run on schedules, no ROS."""

from __future__ import annotations

import numpy as np
import pytest

from vibro_dic.catch_up import CatchUpPolicy, Choice, cdr_stamp_ns, choose, frames_behind, simulate

PERIOD_S = 0.001  # a 1000 Hz camera


def _arrivals(n: int, period_s: float = PERIOD_S) -> list[float]:
    return [k * period_s for k in range(n)]


def test_the_newest_waiting_image_is_tracked_and_the_rest_skipped() -> None:
    assert choose([7]) == Choice(7, [])
    assert choose([3, 4, 5, 6]) == Choice(6, [3, 4, 5])
    with pytest.raises(ValueError):
        choose([])


def test_within_the_bound_the_oldest_is_tracked_and_beyond_it_the_oldest_are_skipped() -> None:
    assert choose([3, 4], max_behind=5) == Choice(3, [], [4])
    assert choose([3, 4, 5, 6, 7], max_behind=2) == Choice(5, [3, 4], [6, 7])
    assert frames_behind(10.0, 1000.0) == 10 and frames_behind(10.0, 2000.0) == 20 and frames_behind(0.0, 1e3) == 0
    with pytest.raises(ValueError):
        choose([1], max_behind=-1)
    with pytest.raises(ValueError):
        frames_behind(float("nan"), 1000.0)


def _jittery_stalls(n: int, every_s: float, length_s: float) -> list[tuple[float, float]]:
    return [(t, t + length_s) for t in np.arange(0.0105, n * PERIOD_S, every_s)]


def test_short_stalls_cost_no_image_within_the_bound_and_one_each_without_it() -> None:
    # a tracker that keeps up on average (0.7 ms of work per 1 ms frame) on a machine that takes its core for
    # 1.5 ms every 20 ms (other processes): two images wait after each such stall
    n, cost = 1000, 0.0007
    stalls = _jittery_stalls(n, 0.02, 0.0015)
    bounded = simulate(_arrivals(n), lambda k, gap: cost, stalls=stalls, max_behind=10)
    assert bounded.tracked == list(range(n)) and not bounded.skipped and not bounded.dropped
    lag = np.array(bounded.finished_s) - np.array(_arrivals(n))
    # behind by at most the stall plus the frames that came during it, caught up before the next stall
    assert lag.max() <= 0.0015 + 2 * cost + 1e-12
    jump = simulate(_arrivals(n), lambda k, gap: cost, stalls=stalls, max_behind=0)
    assert jump.skipped  # the pure jump loses images after the stalls that leave two waiting


def test_a_long_stall_is_one_block_and_the_lag_after_it_is_bounded_by_the_backlog() -> None:
    n, cost, bound = 600, 0.00075, 10
    queue_depth = 30  # a reader queue deeper than the bound: the bound, not the queue, decides what is skipped
    for stall_s in (0.01, 0.05, 0.2):
        stall = (0.1005, 0.1005 + stall_s)
        sim = simulate(_arrivals(n), lambda k, gap: cost, stalls=[stall], queue_depth=queue_depth, max_behind=bound)
        assert set(sim.tracked) | set(sim.skipped) | set(sim.dropped) == set(range(n))
        lost = sorted(sim.skipped + sim.dropped)
        if lost:
            assert lost == list(range(lost[0], lost[-1] + 1))  # one block
        # the backlog left after the stall is at most bound + 1 images, worked through oldest first: the first
        # image that arrived after the stall is done within bound + 2 frames' work
        assert sim.recovery_s[0] <= (bound + 2) * cost + 1e-12
        lag = np.array(sim.finished_s) - np.array([k * PERIOD_S for k in sim.tracked])
        after = np.array([k * PERIOD_S for k in sim.tracked]) >= stall[1]
        assert lag[after].max() <= (bound + 2) * cost + 1e-12


def _hog(start_s: float, end_s: float) -> list[tuple[float, float]]:
    """Another process on the tracker's core: the tracker gets half of it (2 ms of every 4)."""
    return [(t, t + 0.002) for t in np.arange(start_s, end_s, 0.004)]


def _recovery_s(sim, end_s: float, period_s: float = PERIOD_S, lag_s: float = 0.005) -> float:
    """From ``end_s`` to the end of the first frame that arrived after it and was done within ``lag_s``."""
    for k, f in zip(sim.tracked, sim.finished_s):
        if k * period_s >= end_s and f - k * period_s < lag_s:
            return f - end_s
    return float("inf")


def test_after_a_sustained_stall_a_tracker_that_can_keep_up_jumps_and_recovers_at_once() -> None:
    # 300 ms at half a core: the backlog fills to its bound; draining it afterwards on 0.25 ms of spare time per
    # frame would take (bound x 0.75 / 0.25) ms; the policy, behind for catch_up_ms in a row while its own work
    # per frame (0.75 ms) is under the period, jumps instead
    n, cost, bound = 1500, 0.00075, 10
    hog = _hog(0.5, 0.8)
    drained = simulate(_arrivals(n), lambda k, gap: cost, stalls=hog, max_behind=bound)
    policy = simulate(_arrivals(n), lambda k, gap: cost, stalls=hog, max_behind=bound, jump_after_s=0.01)
    assert _recovery_s(policy, 0.8) <= 2 * PERIOD_S + cost  # one jump
    assert _recovery_s(drained, 0.8) > 5 * _recovery_s(policy, 0.8)  # draining the bound's backlog instead
    for sim in (drained, policy):  # every image tracked or reported, the losses inside the hog
        assert set(sim.tracked) | set(sim.skipped) | set(sim.dropped) == set(range(n))
        assert all(500 <= k <= 810 for k in sim.skipped + sim.dropped)
    # and jitter still costs nothing: never behind for 10 ms in a row
    jitter = simulate(_arrivals(n), lambda k, gap: 0.0007, stalls=_jittery_stalls(n, 0.02, 0.0015), max_behind=bound,
                      jump_after_s=0.01)
    assert jitter.tracked == list(range(n))


def test_a_tracker_slower_than_its_camera_never_jumps_it_loses_spread_images() -> None:
    period, cost, n = 0.0005, 0.0007, 2000  # its own work is over the period: it cannot keep up, jumping would
    sim = simulate(_arrivals(n, period), lambda k, gap: cost, max_behind=20, jump_after_s=0.01)  # only lose blocks
    lost = np.array(sorted(sim.skipped + sim.dropped))
    runs = np.split(lost, np.flatnonzero(np.diff(lost) > 1) + 1)
    assert max(len(r) for r in runs) <= int(np.ceil(cost / period))


def test_the_policy_jumps_only_behind_long_enough_and_able_to_keep_up() -> None:
    p = CatchUpPolicy(max_behind=5, period_s=0.001, jump_after_s=0.01)
    assert p.choose([1, 2, 3], 0.0) == Choice(1, [], [2, 3])  # no work measured yet: never a jump
    p.worked(0.0008)
    assert p.choose([2, 3, 4], 0.005) == Choice(2, [], [3, 4])  # behind since 0.0, for 5 ms only
    assert p.choose([3, 4, 5, 6], 0.011) == Choice(6, [3, 4, 5], [])  # 11 ms behind, 0.8 ms < 1 ms: jump
    assert p.jumps == 1 and p.behind_since_s is None
    assert p.choose([7], 0.012) == Choice(7, [], []) and p.behind_since_s is None  # caught up
    slow = CatchUpPolicy(max_behind=5, period_s=0.001, jump_after_s=0.01)
    slow.worked(0.0012)
    slow.choose([1, 2], 0.0)
    assert slow.choose([2, 3, 4], 0.02).track == 2  # cannot keep up: the bound, no jump


def test_a_slower_tracker_with_a_bound_tracks_at_its_own_rate_with_spread_losses() -> None:
    period, cost, n = 0.0005, 0.0007, 2000  # a 2000 Hz camera, 0.7 ms a frame
    sim = simulate(_arrivals(n, period), lambda k, gap: cost, max_behind=20, queue_depth=5)
    span = sim.finished_s[-1] - sim.finished_s[0]
    assert (len(sim.tracked) - 1) / span == pytest.approx(1 / cost, rel=0.01)
    lost = np.array(sorted(sim.skipped + sim.dropped))
    runs = np.split(lost, np.flatnonzero(np.diff(lost) > 1) + 1)
    assert max(len(r) for r in runs) <= int(np.ceil(cost / period))
    lag = np.array(sim.finished_s) - np.array([k * period for k in sim.tracked])
    # an image waits behind at most bound + 1 others, each a frame's work: the lag never grows past that
    assert lag.max() <= 22 * cost + 1e-12


def test_a_stall_is_one_jump_every_image_accounted_for_and_recovery_is_one_frame() -> None:
    n, cost = 400, 0.0006  # keeps up: 0.6 ms of work per 1 ms frame
    stall = (0.1005, 0.1505)  # 50 ms on another process, mid-frame
    sim = simulate(_arrivals(n), lambda k, gap: cost, stalls=[stall], queue_depth=5)
    every = set(sim.tracked) | set(sim.skipped) | set(sim.dropped)
    assert every == set(range(n)) and len(sim.tracked) + len(sim.skipped) + len(sim.dropped) == n  # each once
    # before the stall and after it every image is tracked; the loss is the stall's images, in one block
    lost = sorted(sim.skipped + sim.dropped)
    assert lost == list(range(lost[0], lost[-1] + 1))
    assert 101 <= lost[0] and lost[-1] <= 150
    # bounded catch-up: one jump (the queue's images but the newest skipped at once), then the next image to
    # arrive is tracked as soon as it arrives: done one period + one frame's work after the stall at most
    assert len(sim.skipped) == 4 and len(sim.dropped) == len(lost) - 4
    assert sim.recovery_s[0] <= PERIOD_S + cost + 1e-12


def test_recovery_does_not_grow_with_the_stall_and_is_never_later_than_oldest_first() -> None:
    # per-frame cost growing with the gap as measured on a live tracker that fell behind (0.75 ms a frame, 1.2 ms
    # across 2-3 frames, 1.8 ms beyond): with the jump, two frames' work ends any stall, however long: the jump
    # across the stall (1.8 ms), then one across the images that came meanwhile (2 frames: 1.2 ms)
    cost = lambda k, gap: 0.00075 if gap == 1 else (0.0012 if gap <= 3 else 0.0018)  # noqa: E731
    for stall_s in (0.01, 0.05, 0.2):
        stall = (0.1005, 0.1005 + stall_s)
        new = simulate(_arrivals(600), cost, stalls=[stall])
        old = simulate(_arrivals(600), cost, stalls=[stall], jump=False)
        assert new.recovery_s[0] <= 0.0018 + 0.0012 + 1e-12
        assert new.recovery_s[0] <= old.recovery_s[0]


def test_a_tracker_slower_than_the_camera_tracks_at_its_own_rate_and_loses_spread_images() -> None:
    # a 2000 Hz camera and 0.7 ms a frame (the one-core ceiling 1430 frames/s): no collapse, the tracked rate is
    # the ceiling, and the lost images are spread (never more than a frame or two in a row), not a block
    period, cost, n = 0.0005, 0.0007, 2000
    sim = simulate(_arrivals(n, period), lambda k, gap: cost)
    span = sim.finished_s[-1] - sim.finished_s[0]
    rate = (len(sim.tracked) - 1) / span
    assert rate == pytest.approx(1 / cost, rel=0.01)
    lost = np.array(sorted(sim.skipped + sim.dropped))
    runs = np.split(lost, np.flatnonzero(np.diff(lost) > 1) + 1)
    assert max(len(r) for r in runs) <= int(np.ceil(cost / period))  # at most what arrives during one frame


def test_catch_up_when_the_cost_grows_with_the_gap_bounded_by_the_jump() -> None:
    # a gap costing more per frame (a search instead of the prediction) would feed a collapse oldest-first; with
    # the jump the tracker still ends each stall after one expensive frame
    n = 400
    cost = lambda k, gap: 0.0006 if gap == 1 else 0.0012  # noqa: E731
    sim = simulate(_arrivals(n), cost, stalls=[(0.1005, 0.1505), (0.25, 0.26)])
    assert all(r <= PERIOD_S + 0.0012 + 1e-12 for r in sim.recovery_s)
    assert sim.tracked[-1] == n - 1


def test_the_stamp_is_read_from_the_serialized_image_without_deserializing_it() -> None:
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image

    msg = Image(height=2, width=3, encoding="mono8", step=3, data=bytes(range(6)))
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_764_000_123, 987_654_321
    assert cdr_stamp_ns(serialize_message(msg)) == 1_764_000_123_987_654_321
    with pytest.raises(ValueError):
        cdr_stamp_ns(b"\x00\x01\x00\x00")
