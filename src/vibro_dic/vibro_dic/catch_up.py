"""How a live tracker that falls behind keeps up: which images it tracks, which it reports lost.

No rclpy here. ``dic_tracker`` (live camera), each time it is handed an image, first takes every image already
waiting in its subscription's queue (raw, unread: only their stamps are read, :func:`cdr_stamp_ns`) into its own
backlog. A backlog of up to ``max_behind`` images behind the one tracked is worked through oldest first: a short
stall (another process on its core for a millisecond or two, a slow frame) costs no image, only a few frames of
lag, which the tracker's spare capacity removes (at 0.7 ms of work per 1 ms frame, 10 frames behind are caught
up in about 25 ms). Beyond ``max_behind``, the oldest images are passed over at once and reported lost with
:data:`SKIPPED` as the reason, and the next one tracked is predicted across the gap from the motion history
(vibro_dic.tracker, step 1: quadratic for the ball, the drive's sine for the structure). So a long stall is one
block of skipped images and a lag under ``max_behind + 2`` frames' work, however long the stall; a tracker
slower than its camera tracks at its own rate with the lost images spread (one now and then), not a collapse.
``max_behind = 0`` is the pure jump to the newest image, which loses an image at every jitter.

:func:`simulate` runs this policy (or the oldest-first one without a bound) on a schedule of image arrivals, a
per-frame cost and stalls, deterministically: what the tests and the bench's expectations rest on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

#: reason of a DicFrame whose image was received but passed over for a newer one
SKIPPED = "skipped: the tracker fell behind and jumped to the newest image"


def cdr_stamp_ns(raw: bytes) -> int:
    """The header stamp (ns) of a serialized message whose first field is a std_msgs/Header (sensor_msgs/Image):
    CDR encapsulation (4 bytes: representation id, options), then int32 sec and uint32 nanosec in its byte
    order. Reads 12 bytes; the image itself is never deserialized."""
    if len(raw) < 12:
        raise ValueError(f"a serialized message of {len(raw)} bytes has no header stamp")
    order = "little" if raw[1] & 1 else "big"  # 0x0001 CDR_LE, 0x0000 CDR_BE (and their PL_ variants 2/3)
    sec = int.from_bytes(raw[4:8], order, signed=True)
    nanosec = int.from_bytes(raw[8:12], order)
    return sec * 1_000_000_000 + nanosec


#: (ms of camera time) dic_tracker's default bound on its backlog (parameter ``catch_up_ms``): on 2 cores beside the
#: rest of the live graph at 1000 Hz, 10 ms passed over 14-468 of 3000 images per run, 30 ms 4-26 (bench_live.py)
DEFAULT_CATCH_UP_MS = 30.0


@dataclass
class Choice:
    """The image to track now (its frame index), the frame indices of the waiting images passed over, and those
    left waiting (tracked next, oldest first)."""

    track: int
    skipped: list[int]
    left: list[int] = field(default_factory=list)


def choose(waiting: Sequence[int], max_behind: int = 0) -> Choice:
    """Of the frame indices of the images waiting (arrival order, growing): the newest ``max_behind + 1`` are kept,
    the oldest of them tracked now and the rest left waiting; the older ones are skipped. ``max_behind = 0``: the
    newest is tracked and the rest skipped."""
    if not waiting:
        raise ValueError("no image waiting")
    if max_behind < 0:
        raise ValueError(f"max_behind must be >= 0, got {max_behind}")
    n_skip = max(len(waiting) - (max_behind + 1), 0)
    keep = [int(k) for k in waiting[n_skip:]]
    return Choice(keep[0], [int(k) for k in waiting[:n_skip]], keep[1:])


@dataclass
class CatchUpPolicy:
    """:func:`choose` with a memory: how long the tracker has been behind, and what a frame's own work costs.

    Behind (more than the image about to be tracked waiting) for ``jump_after_s`` of wall time in a row, a
    tracker whose mean work per frame (``work_s``, its own CPU time: not inflated by the stall) is under the
    camera's period jumps to the newest image: it can keep up, so the backlog is the stall's, and draining it on
    the little spare capacity left would keep it behind for many times the stall (recovery in one frame instead).
    Otherwise the backlog is bounded by ``max_behind`` (a short stall costs nothing; a tracker slower than its
    camera loses single images, spread).
    """

    max_behind: int
    period_s: float
    jump_after_s: float
    behind_since_s: float | None = None
    work_s: float | None = None
    jumps: int = 0

    def choose(self, waiting: Sequence[int], now_s: float) -> Choice:
        """The choice for the images ``waiting`` at wall time ``now_s`` (s)."""
        if len(waiting) <= 1:
            self.behind_since_s = None
        elif self.behind_since_s is None:
            self.behind_since_s = now_s
        jump = (self.behind_since_s is not None and now_s - self.behind_since_s >= self.jump_after_s
                and self.work_s is not None and self.work_s < self.period_s)
        if jump:
            self.behind_since_s = None
            self.jumps += 1
        return choose(waiting, 0 if jump else self.max_behind)

    def worked(self, seconds: float) -> None:
        """A tracked frame's own work (s): the running mean ``work_s`` (weight 0.1 on the newest)."""
        self.work_s = seconds if self.work_s is None else 0.9 * self.work_s + 0.1 * seconds


def frames_behind(catch_up_ms: float, fps: float) -> int:
    """The backlog bound in frames for ``catch_up_ms`` of camera time at ``fps`` (0 for 0 ms: always the newest)."""
    if not (math.isfinite(catch_up_ms) and catch_up_ms >= 0):
        raise ValueError(f"catch_up_ms must be a time in ms >= 0, got {catch_up_ms}")
    return int(round(catch_up_ms * 1e-3 * fps))


@dataclass
class CatchUpStats:
    """What the jumps cost a live session: images skipped, episodes (calls that skipped any), the largest."""

    skipped: int = 0
    episodes: int = 0
    largest: int = 0
    last: tuple[int, int] | None = None  # (first, last) frame index of the latest episode's skipped images

    def add(self, choice: Choice) -> None:
        if not choice.skipped:
            return
        self.skipped += len(choice.skipped)
        self.episodes += 1
        self.largest = max(self.largest, len(choice.skipped))
        self.last = (choice.skipped[0], choice.skipped[-1])


@dataclass
class Simulation:
    """Outcome of :func:`simulate`: frame indices tracked (with the time each finished), skipped (received and
    passed over), dropped (pushed out of the reader's queue before being taken), and per stall the time from its
    end to the end of the first frame tracked that arrived after it (``recovery_s``)."""

    tracked: list[int] = field(default_factory=list)
    finished_s: list[float] = field(default_factory=list)
    skipped: list[int] = field(default_factory=list)
    dropped: list[int] = field(default_factory=list)
    recovery_s: list[float] = field(default_factory=list)


def simulate(arrivals_s: Sequence[float], cost_s: Callable[[int, int], float], *,
             stalls: Sequence[tuple[float, float]] = (), queue_depth: int = 5, jump: bool = True,
             max_behind: int = 0, jump_after_s: float | None = None) -> Simulation:
    """Frame k arrives at ``arrivals_s[k]`` into a keep-last queue of ``queue_depth``; the tracker, whenever it is
    free and an image waits, takes what waits (``jump``: all of it into its backlog, then :func:`choose` with
    ``max_behind``; else the oldest only, the queue bounding nothing but itself) and is busy for ``cost_s(k, gap)``
    (gap: frames since the last one tracked); during a stall (start, end) it does nothing. ``jump_after_s``: the
    :class:`CatchUpPolicy` with that time, the arrivals' median interval as the period."""
    sim = Simulation()
    queue: list[int] = []
    backlog: list[int] = []  # taken from the queue (jump): the tracker's own, unbounded by queue_depth
    nxt = 0  # next frame to arrive
    now = 0.0
    last = None
    n = len(arrivals_s)
    stalls = sorted(stalls)
    pending_stalls = list(stalls)
    policy = None
    if jump_after_s is not None:
        period = sorted(b - a for a, b in zip(arrivals_s, arrivals_s[1:]))[(n - 1) // 2] if n > 1 else math.inf
        policy = CatchUpPolicy(max_behind, period, jump_after_s)

    def arrive_until(t: float) -> None:
        nonlocal nxt
        while nxt < n and arrivals_s[nxt] <= t:
            queue.append(nxt)
            nxt += 1
            if len(queue) > queue_depth:
                sim.dropped.append(queue.pop(0))

    while nxt < n or queue or backlog:
        arrive_until(now)
        if pending_stalls and pending_stalls[0][0] <= now:
            start, end = pending_stalls.pop(0)
            if end > now:  # busy elsewhere: images keep arriving (and being dropped)
                arrive_until(end)
                now = end
            continue
        if not queue and not backlog:
            now = max(now, arrivals_s[nxt])
            if pending_stalls and pending_stalls[0][0] < now:
                now = pending_stalls[0][0]
            continue
        if jump:
            backlog += queue
            queue.clear()
            choice = policy.choose(backlog, now) if policy is not None else choose(backlog, max_behind)
            backlog[:] = choice.left
        else:
            choice = Choice(queue.pop(0), [])
        sim.skipped += choice.skipped
        k = choice.track
        gap = k - last if last is not None else 1
        work = cost_s(k, gap)
        now += work
        if policy is not None:
            policy.worked(work)
        sim.tracked.append(k)
        sim.finished_s.append(now)
        last = k
    for _, end in stalls:
        after = [f for k, f in zip(sim.tracked, sim.finished_s) if arrivals_s[k] >= end]
        sim.recovery_s.append(after[0] - end if after else math.nan)
    return sim
