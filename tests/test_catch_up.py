"""The live tracker's catch-up policy (vibro_dic.catch_up): a backlog the tracker can work off within catch_up_s is
tracked oldest first (a short stall costs no image); beyond that every stride-th image is tracked and the others
skipped and reported (losses spread, the lag worked off within catch_up_s); a tracker slower than its camera tracks
at its own rate with spread losses; catch_up 0 is the jump to the newest image. Run on
schedules, no ROS."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vibro_dic.catch_up import KEEPING_UP_S, CatchUpPolicy, Choice, cdr_stamp_ns, choose, simulate, stride_for, thin

PERIOD_S = 0.001  # a 1000 Hz camera
CATCH_UP_S = 0.03  # dic_tracker's default catch_up_ms


def _arrivals(n: int, period_s: float = PERIOD_S) -> list[float]:
    return [k * period_s for k in range(n)]


def _runs(lost: list[int]) -> list[int]:
    """Lengths of the runs of consecutive frame indices in ``lost`` ([0] when none)."""
    lost = np.array(sorted(lost))
    if not len(lost):
        return [0]
    return [len(r) for r in np.split(lost, np.flatnonzero(np.diff(lost) > 1) + 1)]


def _every_image_once(sim, n: int) -> None:
    assert sorted(sim.tracked + sim.skipped + sim.dropped) == list(range(n))


def test_the_newest_waiting_image_is_tracked_and_the_rest_skipped() -> None:
    assert choose([7]) == Choice(7, [])
    assert choose([3, 4, 5, 6]) == Choice(6, [3, 4, 5])
    with pytest.raises(ValueError):
        choose([])


def test_thinning_skips_stride_minus_one_and_tracks_the_next() -> None:
    assert thin([3, 4, 5, 6], 1) == Choice(3, [], [4, 5, 6])
    assert thin([3, 4, 5, 6], 3) == Choice(5, [3, 4], [6])
    assert thin([3, 4], 5) == Choice(4, [3], [])  # fewer waiting: the newest
    for bad in (lambda: thin([], 1), lambda: thin([1], 0)):
        with pytest.raises(ValueError):
            bad()


def test_the_stride_is_the_smallest_that_works_the_backlog_off_in_time() -> None:
    # 0.5 ms of work per 1 ms frame: 0.5 ms of spare time per frame tracked, so 30 frames behind take 30 ms
    assert stride_for(0, 0.0005, PERIOD_S, CATCH_UP_S) == 1
    assert stride_for(30, 0.0005, PERIOD_S, CATCH_UP_S) == 1
    assert stride_for(31, 0.0005, PERIOD_S, CATCH_UP_S) == 2
    assert stride_for(1, 0.0007, 0.0005, CATCH_UP_S) == 2  # slower than its camera: never every image
    assert stride_for(9, 0.0005, PERIOD_S, 0.0) == 10  # catch_up 0: the newest
    rng = np.random.default_rng(4)
    for _ in range(200):  # the definition: the backlog left after catch_up_s at that stride is none, and at one less
        behind, cost = int(rng.integers(1, 400)), float(rng.uniform(1e-4, 2e-3))  # it is some (when > 1)
        s = stride_for(behind, cost, PERIOD_S, CATCH_UP_S)
        assert behind - (s - cost / PERIOD_S) * CATCH_UP_S / cost <= 1e-6 or s == behind + 1
        assert s == 1 or behind - (s - 1 - cost / PERIOD_S) * CATCH_UP_S / cost > 0
    for bad in ((-1, 1e-3, 1e-3, 0.03), (1, -1e-3, 1e-3, 0.03), (1, 1e-3, 0.0, 0.03), (1, 1e-3, 1e-3, -1.0)):
        with pytest.raises(ValueError):
            stride_for(*bad)


def test_the_policy_tracks_every_image_until_it_knows_its_cost_and_refuses_nonsense() -> None:
    p = CatchUpPolicy(PERIOD_S, CATCH_UP_S, keeping_up_s=0.0)
    assert p.choose([1, 2, 3, 4, 5, 6], 0.0) == Choice(1, [], [2, 3, 4, 5, 6]) and p.stride == 1
    p.worked(0.0009)  # 0.9 ms of 1: 0.1 ms spare per frame, 3 frames in 30 ms (one waiting is no lag)
    assert p.choose([2, 3, 4, 5, 6], 0.001).track == 2 and p.stride == 1  # 3 in the 29 ms left: in time
    assert p.choose([3, 4, 5, 6, 7, 8], 0.002) == Choice(4, [3], [5, 6, 7, 8]) and p.stride == 2  # 4: not
    # a backlog of a few milliseconds is keeping up: no deadline, every image
    q = CatchUpPolicy(PERIOD_S, CATCH_UP_S)
    q.worked(0.0009)
    few = list(range(1, int(KEEPING_UP_S / PERIOD_S) + 2))
    assert q.choose(few, 0.0) == Choice(1, [], few[1:]) and q.deadline_s is None
    assert q.choose(few + [few[-1] + 1], 0.0).track == 1 and q.deadline_s == CATCH_UP_S  # one more: the clock runs
    newest = CatchUpPolicy(PERIOD_S, 0.0)  # catch_up 0: the newest, whatever the lag
    assert newest.choose([4, 5], 0.0) == Choice(5, [4], [])
    for bad in ((0.0, 0.03), (math.nan, 0.03), (1e-3, -0.01), (1e-3, math.inf)):
        with pytest.raises(ValueError):
            CatchUpPolicy(*bad)
    with pytest.raises(ValueError):
        CatchUpPolicy(PERIOD_S, CATCH_UP_S, keeping_up_s=-1.0)


def _jittery_stalls(n: int, every_s: float, length_s: float) -> list[tuple[float, float]]:
    return [(t, t + length_s) for t in np.arange(0.0105, n * PERIOD_S, every_s)]


def test_short_stalls_cost_no_image() -> None:
    # a tracker that keeps up on average (0.7 ms of work per 1 ms frame) on a machine that takes its core for
    # 1.5 ms every 20 ms (other processes): two images wait after each such stall
    n, cost = 1000, 0.0007
    stalls = _jittery_stalls(n, 0.02, 0.0015)
    sim = simulate(_arrivals(n), lambda k, gap: cost, stalls=stalls, catch_up_s=CATCH_UP_S)
    assert sim.tracked == list(range(n)) and not sim.skipped and not sim.dropped
    lag = np.array(sim.finished_s) - np.array(_arrivals(n))
    # behind by at most the stall plus the frames that came during it, caught up before the next stall
    assert lag.max() <= 0.0015 + 2 * cost + 1e-12
    jump = simulate(_arrivals(n), lambda k, gap: cost, stalls=stalls)
    assert jump.skipped  # the pure jump loses images after the stalls that leave two waiting


def _recovery_s(sim, end_s: float, period_s: float = PERIOD_S, lag_s: float = KEEPING_UP_S + 0.002,
                until_s: float = math.inf) -> float:
    """From ``end_s`` to the end of the first frame that arrived after it and was done within ``lag_s``, after
    which every frame that arrived before ``until_s`` is done within ``lag_s``."""
    done = [(k * period_s, f) for k, f in zip(sim.tracked, sim.finished_s) if end_s <= k * period_s < until_s]
    late = [i for i, (t, f) in enumerate(done) if f - t >= lag_s]
    first = late[-1] + 1 if late else 0
    return done[first][1] - end_s if first < len(done) else math.inf


@pytest.mark.parametrize("stall_s", [0.04, 0.1, 0.3])
def test_a_long_stall_loses_spread_images_and_is_worked_off_within_catch_up(stall_s: float) -> None:
    n, cost = 1000, 0.0006
    stall = (0.1005, 0.1005 + stall_s)
    # a reader queue that holds the stall's images: the policy, not the queue, decides what is lost
    sim = simulate(_arrivals(n), lambda k, gap: cost, stalls=[stall], queue_depth=1000, catch_up_s=CATCH_UP_S)
    _every_image_once(sim, n)
    assert not sim.dropped
    lost = sim.skipped
    assert all(stall[0] <= k * PERIOD_S <= stall[1] + CATCH_UP_S for k in lost)  # the stall's and the catch-up's
    # spread: never more in a row than the stride the largest backlog (the stall's images) asks for, less one
    worst = stride_for(math.ceil(stall_s / PERIOD_S) + 1, cost, PERIOD_S, CATCH_UP_S)
    assert max(_runs(lost)) <= worst - 1
    # not a block: of every flight-long stretch (20 ms) of the stall, images are tracked
    tracked = np.array(sim.tracked) * PERIOD_S
    for t in np.arange(stall[0], stall[1] - 0.02, 0.02):
        assert np.any((tracked >= t) & (tracked < t + 0.02)), t
    # and the lag is worked off within catch_up_s (plus a frame's work and the period: a new image to track)
    assert _recovery_s(sim, stall[1]) <= CATCH_UP_S + cost + PERIOD_S + 1e-9


def _hog(start_s: float, end_s: float) -> list[tuple[float, float]]:
    """Another process on the tracker's core: the tracker gets half of it (2 ms of every 4)."""
    return [(t, t + 0.002) for t in np.arange(start_s, end_s, 0.004)]


def test_a_tracker_on_half_a_core_loses_spread_images_and_recovers_within_catch_up_after() -> None:
    # 0.7 ms a frame on half a core is 1.4 ms per 1 ms frame: it cannot keep up while the hog lasts
    n, cost = 1500, 0.0007
    sim = simulate(_arrivals(n), lambda k, gap: cost, stalls=_hog(0.5, 0.8), queue_depth=50, catch_up_s=CATCH_UP_S)
    _every_image_once(sim, n)
    lost = sim.skipped + sim.dropped
    assert lost and all(0.5 <= k * PERIOD_S <= 0.8 + CATCH_UP_S for k in lost)
    assert max(_runs(lost)) <= 2
    assert _recovery_s(sim, 0.8) <= CATCH_UP_S + cost + PERIOD_S + 1e-9


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
    # the ceiling, the lost images are spread (never more than a frame or two in a row), and the lag stays small
    period, cost, n = 0.0005, 0.0007, 2000
    for sim in (simulate(_arrivals(n, period), lambda k, gap: cost),
                simulate(_arrivals(n, period), lambda k, gap: cost, queue_depth=50, catch_up_s=CATCH_UP_S)):
        _every_image_once(sim, n)
        span = sim.finished_s[-1] - sim.finished_s[0]
        assert (len(sim.tracked) - 1) / span == pytest.approx(1 / cost, rel=0.01)
        assert max(_runs(sim.skipped + sim.dropped)) <= int(np.ceil(cost / period))  # what arrives in one frame
        lag = np.array(sim.finished_s) - np.array([k * period for k in sim.tracked])
        assert lag.max() <= CATCH_UP_S


def test_catch_up_when_the_cost_grows_with_the_gap() -> None:
    # a frame after a gap costing twice the next frame (a search instead of the prediction): the stride's estimate
    # learns it, and each stall is still worked off within catch_up_s
    n = 600
    cost = lambda k, gap: 0.0005 if gap == 1 else 0.001  # noqa: E731
    stalls = [(0.1005, 0.1505), (0.3, 0.31)]
    sim = simulate(_arrivals(n), cost, stalls=stalls, queue_depth=100, catch_up_s=CATCH_UP_S)
    _every_image_once(sim, n)
    for (_, end), (until, _) in zip(stalls, stalls[1:] + [(math.inf, math.inf)]):
        assert _recovery_s(sim, end, until_s=until) <= CATCH_UP_S + 0.001 + PERIOD_S + 1e-9
    assert sim.tracked[-1] == n - 1
    jump = simulate(_arrivals(n), cost, stalls=stalls)  # the pure jump: each stall ends after one expensive frame
    assert all(r <= PERIOD_S + 0.001 + 1e-12 for r in jump.recovery_s)


def test_the_stamp_is_read_from_the_serialized_image_without_deserializing_it() -> None:
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Image

    msg = Image(height=2, width=3, encoding="mono8", step=3, data=bytes(range(6)))
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_764_000_123, 987_654_321
    assert cdr_stamp_ns(serialize_message(msg)) == 1_764_000_123_987_654_321
    with pytest.raises(ValueError):
        cdr_stamp_ns(b"\x00\x01\x00\x00")
