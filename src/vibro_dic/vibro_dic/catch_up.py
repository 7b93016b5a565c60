"""How a live tracker that falls behind keeps up: which images it tracks, which it reports lost.

No rclpy here. ``dic_tracker`` (live camera), each time it is handed an image, first takes every image already
waiting in its subscription's queue (raw, unread: only their stamps are read,
:func:`vibro_dic.raw_image.cdr_stamp_ns`) into its own backlog. It then tracks one image of the backlog and reports
the older ones it passed over lost, with :data:`SKIPPED` as the reason; the next image tracked is predicted across
the gap from the motion history (vibro_dic.tracker, step 1: quadratic for the ball, the drive's sine for the
structure).

Which one (:func:`stride_for`, :class:`CatchUpPolicy`): the backlog must be worked off within ``catch_up_s`` (the
node's ``catch_up_ms``) of the moment the tracker first found more images waiting than a few milliseconds'
worth (:data:`KEEPING_UP_S`: on busy cores a backlog wanders over a few frames without a stall), back to that few (a
deadline: reached with more waiting, it takes the newest). A tracker whose own work is ``cost_s`` per image (its
CPU time: a stall, when another process has its core, is not work) and that advances ``stride`` images per image
tracked removes ``stride - cost_s / period_s`` images of backlog in ``cost_s``; ``behind`` images are gone in
``catch_up_s`` when

    stride >= cost_s / period_s + behind * cost_s / catch_up_s.

The smallest such whole stride is taken: 1 (every image, oldest first) while the backlog can be worked off in
time, so a short stall (another process on the core for a millisecond or two, a slow frame) costs no image, only
a few frames of lag; after a long stall every ``stride``-th image is tracked and the rest skipped, the stride
falling back to 1 as the backlog goes (lost images spread, one or a few in a row, not a block: every flight of
the ball keeps images); a tracker slower than its camera (``cost_s > period_s``) tracks every 2nd (3rd, ...)
image at its own rate with a lag of a few frames. ``catch_up_s = 0``: always the newest image.

:func:`simulate` runs a policy on a schedule of image arrivals, a per-frame cost and stalls, deterministically:
what the tests and the bench's expectations rest on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

from .raw_image import cdr_stamp_ns  # noqa: F401  (the stamp of a serialized image: read here, kept there)

#: reason of a DicFrame whose image was received but passed over for a newer one
SKIPPED = "skipped: the tracker fell behind and jumped to the newest image"


#: (ms) dic_tracker's default ``catch_up_ms``: the time within which a tracker that fell behind has worked off its
#: backlog (the live goal: back at the camera within 50 ms of a stall's end, with margin for the cost's estimate)
DEFAULT_CATCH_UP_MS = 30.0


@dataclass
class Choice:
    """The image to track now (its frame index), the frame indices of the waiting images passed over, and those
    left waiting (tracked next, oldest first)."""

    track: int
    skipped: list[int]
    left: list[int] = field(default_factory=list)


def choose(waiting: Sequence[int]) -> Choice:
    """Of the frame indices of the images waiting (arrival order, growing): the newest tracked, the rest skipped
    (``catch_up_ms`` 0, the pure jump)."""
    return thin(waiting, len(waiting))


def thin(waiting: Sequence[int], stride: int) -> Choice:
    """Of the images waiting (frame indices, arrival order): the oldest ``stride - 1`` skipped, the next tracked,
    the rest left waiting; the newest tracked when fewer wait."""
    if not waiting:
        raise ValueError("no image waiting")
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    i = min(stride, len(waiting)) - 1
    return Choice(int(waiting[i]), [int(k) for k in waiting[:i]], [int(k) for k in waiting[i + 1:]])


def stride_for(behind: int, cost_s: float, period_s: float, catch_up_s: float) -> int:
    """Images to advance per image tracked (>= 1) so that ``behind`` images of backlog are worked off within
    ``catch_up_s`` (s) by a tracker whose work per image is ``cost_s`` (s) at a camera period ``period_s`` (s): the
    smallest whole stride >= cost_s / period_s + behind * cost_s / catch_up_s (module doc). ``catch_up_s = 0``
    with a backlog: the whole backlog (``behind + 1``, the newest image)."""
    if behind < 0 or not (cost_s >= 0 and period_s > 0 and catch_up_s >= 0):
        raise ValueError(f"stride_for: behind {behind}, cost {cost_s} s, period {period_s} s, catch_up {catch_up_s} s")
    if behind == 0:
        return 1
    if catch_up_s == 0:
        return behind + 1
    need = cost_s / period_s + behind * cost_s / catch_up_s
    return max(1, min(behind + 1, math.ceil(need - 1e-9)))


#: (s) a lag that still counts as keeping up: no deadline runs while the images waiting behind the one taken are
#: at most this much camera time (and at least one image: images arrive in pairs now and then). On 2 busy cores the
#: tracker shares its core with the rest of the graph, and its backlog wanders over a few frames without a stall;
#: 3 ms of backlog plus a frame's work and the transport is under the live goal's 5 ms lag ("back at the camera")
KEEPING_UP_S = 0.003


@dataclass
class CatchUpPolicy:
    """:func:`stride_for` towards a deadline, with a memory of what a frame's own work costs.

    The costs: the tracker's CPU time per image tracked (not inflated by a stall; running means, weight 0.1 on the
    newest), ``cost_s`` of an image tracked next to the one before (stride 1) and ``gap_cost_s`` of one tracked
    across a gap (stride above 1: the prediction across it misses more often, and the search costs more). Two
    costs, so that a tracker whose frames across a gap cost more than the camera's period is not held at stride 2
    once its backlog is gone.

    The deadline: when the tracker finds more images waiting behind the one it takes than ``keeping_up_s`` of camera
    time (:data:`KEEPING_UP_S`; one image at least), it has ``catch_up_s`` from then until they are that few again.
    Each choice takes stride 1 while that works the excess off by the deadline at ``cost_s``, else the stride
    :func:`stride_for` gives for the time left at ``gap_cost_s`` (``cost_s`` until a gap was measured), 2 at
    least; at the deadline, the newest image. So the lag after a stall is gone ``catch_up_s``
    after it, whatever the costs' estimates, and the images lost meanwhile are spread. Before any work is measured
    every image is tracked oldest first (and the deadline holds)."""

    period_s: float
    catch_up_s: float
    keeping_up_s: float = KEEPING_UP_S
    cost_s: float | None = None
    gap_cost_s: float | None = None
    deadline_s: float | None = None  # of the catch-up under way (None: not behind)
    stride: int = 1  # of the latest choice

    def __post_init__(self) -> None:
        if not (math.isfinite(self.keeping_up_s) and self.keeping_up_s >= 0):
            raise ValueError(f"keeping_up_s must be a time in s >= 0, got {self.keeping_up_s}")
        if not (math.isfinite(self.period_s) and self.period_s > 0):
            raise ValueError(f"the camera period must be > 0 s, got {self.period_s}")
        if not (math.isfinite(self.catch_up_s) and self.catch_up_s >= 0):
            raise ValueError(f"catch_up_ms must be a time in ms >= 0, got {1e3 * self.catch_up_s}")

    def choose(self, waiting: Sequence[int], now_s: float) -> Choice:
        """The choice for the images ``waiting`` (frame indices, arrival order) at ``now_s`` (s, monotonic)."""
        behind = len(waiting) - 1
        excess = behind - max(1, int(self.keeping_up_s / self.period_s + 1e-9))
        if self.catch_up_s == 0:  # always the newest
            self.stride = behind + 1
        elif excess <= 0:
            self.deadline_s = None
            self.stride = 1
        else:
            if self.deadline_s is None:
                self.deadline_s = now_s + self.catch_up_s
            left_s = self.deadline_s - now_s
            if left_s <= 0:
                self.stride = behind + 1
            elif self.cost_s is None or stride_for(excess, self.cost_s, self.period_s, left_s) == 1:
                self.stride = 1
            else:
                cost = self.gap_cost_s if self.gap_cost_s is not None else self.cost_s
                self.stride = max(2, stride_for(excess, cost, self.period_s, left_s))
        return thin(waiting, self.stride)

    def worked(self, seconds: float) -> None:
        """The own work (s) of the image just tracked, the latest choice's."""
        if self.stride > 1:
            self.gap_cost_s = seconds if self.gap_cost_s is None else 0.9 * self.gap_cost_s + 0.1 * seconds
        else:
            self.cost_s = seconds if self.cost_s is None else 0.9 * self.cost_s + 0.1 * seconds


@dataclass
class CatchUpStats:
    """What catching up cost a live session: images skipped, episodes (choices that skipped any), the largest."""

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
             catch_up_s: float | None = None) -> Simulation:
    """Frame k arrives at ``arrivals_s[k]`` into a keep-last queue of ``queue_depth``; the tracker, whenever it is
    free and an image waits, takes what waits (``jump``: all of it into its backlog, then with ``catch_up_s`` the
    :class:`CatchUpPolicy`, the arrivals' median interval as the period, else :func:`choose`, the newest; without
    ``jump`` the oldest only, the queue bounding nothing but itself) and is busy for ``cost_s(k, gap)`` (gap: frames
    since the last one tracked); during a stall (start, end) it does nothing."""
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
    if catch_up_s is not None:
        period = sorted(b - a for a, b in zip(arrivals_s, arrivals_s[1:]))[(n - 1) // 2] if n > 1 else 1.0
        policy = CatchUpPolicy(period, catch_up_s)

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
            choice = policy.choose(backlog, now) if policy is not None else choose(backlog)
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
