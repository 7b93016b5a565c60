"""A node's outputs wait for their DECLARED readers, by node name, so the graph starts in any order.

The node table (``vibro_bringup.graph_spec``) says which nodes read each node's outputs; the
launch file and ``vibro graph`` pass that list to the node as the parameter ``readers``
(e.g. ``frame_source: readers: [dic_tracker, recorder]``). With :class:`ReaderGate`:

* a source sends nothing, and ``dic_tracker`` holds its results, until every declared reader
  is matched on the node's topics (seen by node name in its own namespace in the ROS graph,
  and counted as matched by DDS, for ``settle_s``) -- :attr:`ReaderGate.open`. With
  ``reader_topics`` (``reader=topic`` pairs, from the node table) a reader counts only once it is
  matched on every topic listed for it: each subscription of a node is discovered on its own, so
  being seen on one topic (vibro/status) says nothing of another (vibro/simulation); a reader
  without pairs counts once seen on any of the node's topics;
* a node that has finished (``finish()``) exits only once every declared reader it still
  expects is matched and has acknowledged everything the node published, so its latched
  results and end-of-stream status reach readers that started late. A reader seen earlier
  that has left since is not waited for (it finished, or it died and will be restarted);
* while readers are missing, it logs who every ``log_every_s`` and says so on /diagnostics;
  after ``wait_for_readers_s`` it fails loudly: an error naming the missing readers and exit
  code 1, never streaming to nobody.

``exit_when_done`` (true for a recording, false for a live graph) decides whether a
processing node exits once its inputs have ended; sources always end with their file.

``keep_history_until`` (stream names; the node table fills it with the final streams of the node's
stateful readers): once finished, the node stays up until each of these streams has announced its
end on vibro/status, so that a reader restarted mid-run (tracker, fitter, simulator, ...) still
receives what it needs from it: the latched histories of vibro/dic and vibro/accel, latched results,
and the end-of-stream statuses (a source that has exited cannot repeat its own).
"""

from __future__ import annotations

import time
from typing import Callable, Sequence

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.task import Future

from vibro_model.errors import RecordingError
from vibro_msgs.msg import StreamStatus

from . import topics
from .adaptive_qos import results_subscription
from .node_support import declare, run_id_parameter, stop_requested

#: Parameter names, one definition for the nodes and the node table.
READERS = "readers"
READER_TOPICS = "reader_topics"
WAIT_FOR_READERS_S = "wait_for_readers_s"
EXIT_WHEN_DONE = "exit_when_done"


def declare_readiness_parameters(node: Node, default_readers: Sequence[str] = ()) -> tuple[list[str], float, bool]:
    """Declare ``readers`` (default ``default_readers``), ``wait_for_readers_s`` and ``exit_when_done``;
    return their values."""
    readers = declare(node, READERS, list(default_readers) or [""],
                      "node names (in this node's namespace) that read its outputs: its data waits until all "
                      "have matched, and it exits only once they acknowledged")
    wait_s = float(declare(node, WAIT_FOR_READERS_S, 60.0, "fail (exit code 1, naming the readers) when declared "
                                                     "readers are still missing after this long (s)"))
    exit_when_done = bool(declare(node, EXIT_WHEN_DONE, True, "exit once the inputs have ended and the final outputs "
                                                        "are acknowledged (false: stay up, live graph)"))

    names = [str(r).strip() for r in readers if str(r).strip()]
    bad = [r for r in names if "/" in r or " " in r]
    if bad:
        raise RecordingError(f"{node.get_name()}: parameter '{READERS}' takes plain node names, got {bad}")
    if not wait_s > 0:
        raise RecordingError(f"{node.get_name()}: parameter '{WAIT_FOR_READERS_S}' must be > 0, got {wait_s}")
    return sorted(set(names)), wait_s, exit_when_done


def declare_reader_topics(node: Node, readers: Sequence[str]) -> dict[str, set[str]]:
    """Declare ``reader_topics`` (``reader=topic`` pairs: the topics of this node each declared reader must be
    matched on) and return reader -> fully qualified topic names. Refuses a malformed pair; pairs of a reader
    not in ``readers`` are ignored with a warning."""
    values = declare(node, READER_TOPICS, [""],
                     "reader=topic pairs: a declared reader counts as matched only once it is matched on each topic "
                     "listed for it (readers without a pair: on any of this node's topics)")
    out: dict[str, set[str]] = {}
    for value in (str(v).strip() for v in values):
        if not value:
            continue
        reader, sep, topic = value.partition("=")
        if not sep or not reader or not topic or "/" in reader:
            raise RecordingError(f"{node.get_name()}: parameter '{READER_TOPICS}' takes reader=topic pairs "
                                 f"(e.g. recorder=vibro/frames), got {value!r}")
        out.setdefault(reader, set()).add(node.resolve_topic_name(topic))
    ignored = sorted(set(out) - set(readers))
    if ignored:  # e.g. 'readers' overridden in a params file: the pairs of a reader not waited for do not apply
        node.get_logger().warning(f"parameter '{READER_TOPICS}' names {', '.join(ignored)}, not among the declared "
                                  f"'{READERS}' {list(readers)}: their pairs are ignored")
    return {r: t for r, t in out.items() if r in readers}


def declare_keep_history_until(node: Node) -> list[str]:
    """Declare ``keep_history_until`` (see the module doc) and return its stream names."""
    values = declare(node, "keep_history_until", [""],
                     "end-of-stream statuses (vibro/status stream names) to wait for before exiting, keeping this "
                     "node's latched history for a reader restarted mid-run")
    names = sorted({str(v).strip() for v in values if str(v).strip()})
    unknown = [n for n in names if n not in topics.STATUS_STREAMS]
    if unknown:  # a typo would keep the node waiting for a status that never comes, until the run's timeout

        raise RecordingError(f"{node.get_name()}: parameter 'keep_history_until' names unknown streams {unknown}; "
                             f"known: {', '.join(topics.STATUS_STREAMS)}")
    return names


class ReaderGate:
    """The declared readers of a node's outputs (see the module doc). The node spins; the gate polls.

    ``done`` completes when the node may exit (after :meth:`finish`, or on failure);
    ``exit_code`` is then 0, or 1 when the declared readers never came.
    """

    def __init__(self, node: Node, *, on_open: Callable[[], None] | None = None, health=None,
                 settle_s: float = 0.3, poll_s: float = 0.05, log_every_s: float = 5.0,
                 default_readers: Sequence[str] = ()):
        self.node = node
        self.readers, self.wait_s, self.exit_when_done = declare_readiness_parameters(node, default_readers)
        self.reader_topics = declare_reader_topics(node, self.readers)
        self._checked_topics = False
        self.keep_until = declare_keep_history_until(node)
        self.streams_ended: set[str] = set()
        if self.keep_until:

            results_subscription(node, StreamStatus, topics.STATUS.name,
                                 lambda m: self.streams_ended.add(m.stream) if m.finished else None)
        self.health = health
        self.settle_s = settle_s
        self.log_every_s = log_every_s
        self.on_open = on_open
        self.done = Future()
        self.exit_code = 0
        self.open = not self.readers
        self.seen: set[str] = set()
        self.present: set[str] = set()
        self._matched_since: float | None = None
        self._waiting_since: float | None = None  # data held (or exit requested) since
        self._finishing = False
        self._last_log = 0.0
        self._ticks = 0
        self._timer = node.create_timer(poll_s, self._poll)

    # ------------------------------------------------------------------ what the node calls
    def start_clock(self) -> None:
        """Data is waiting for the readers from now on (the ``wait_for_readers_s`` limit runs)."""
        if self._waiting_since is None and not self.open:
            self._waiting_since = time.monotonic()

    def finish(self, always: bool = False, keep_history: bool = True) -> None:
        """The node's outputs are final: exit once the readers have them (when ``exit_when_done``, or
        ``always``: a source ends with its input). ``keep_history`` False: do not wait for
        ``keep_history_until`` (a node that refused its run: the run ends, no reader will be restarted)."""
        if not keep_history:
            self.keep_until = []
        if (self.exit_when_done or always) and not self._finishing:
            self._finishing = True
            self._waiting_since = time.monotonic()
            self._poll()

    @property
    def publishers(self) -> list[Publisher]:
        """Every output of the node: its data or results, vibro/status, /diagnostics."""
        return [p for p in self.node.publishers if p.topic_name != "/parameter_events"]

    # ------------------------------------------------------------------ polling
    def _matched(self) -> set[str]:
        """Declared readers subscribed, in this node's namespace, to each of their ``reader_topics`` (a reader
        without pairs: to any of the publishers' topics), where DDS has matched at least as many subscriptions
        as the ROS graph names."""
        ns = self.node.get_namespace()
        on_topic: dict[str, set[str]] = {}
        for pub in self.publishers:
            names = {i.node_name for i in self.node.get_subscriptions_info_by_topic(pub.topic_name)
                     if i.node_namespace == ns and i.node_name in self.readers}
            if pub.get_subscription_count() < len(names):
                return set()  # named in the graph, not yet matched by DDS: not yet
            on_topic[pub.topic_name] = names
        anywhere = set().union(*on_topic.values()) if on_topic else set()
        return {r for r in anywhere if all(r in on_topic.get(t, ()) for t in self.reader_topics.get(r, ()))}

    def _check_reader_topics(self) -> bool:
        """Every topic in ``reader_topics`` is one this node publishes (a typo would wait for a match that cannot
        come, then blame the reader); otherwise fail with exit code 2 naming it."""
        self._checked_topics = True
        published = {p.topic_name for p in self.publishers}
        unknown = sorted({t for ts in self.reader_topics.values() for t in ts} - published)
        if unknown:

            self.done.set_exception(RecordingError(
                f"{self.node.get_name()}: parameter '{READER_TOPICS}' names topics this node does not publish: "
                f"{', '.join(unknown)} (it publishes {', '.join(sorted(published))})"))
        return not unknown

    def missing(self) -> list[str]:
        """Declared readers the node is waiting for now (at the end: not counting those that came and left)."""
        expected = set(self.readers) - self.seen if self._finishing else set(self.readers)
        return sorted(expected - self.present)

    def _acknowledged(self, timeout_s: float = 0.5) -> bool:
        """Every reliable reader has acknowledged everything published so far (blocks up to ``timeout_s``:
        acknowledgements follow the writer's periodic heartbeats, 0.1 s with vibro's DDS profile, and with
        nothing else to do the node publishes nothing new meanwhile; a zero timeout is never true across
        processes). Short, and never after a stop signal: the wait is a C call no signal interrupts, and a
        poll blocking for seconds in a row kept a node whose readers had died from ever seeing SIGINT
        (launch escalated to SIGKILL)."""
        from rclpy.duration import Duration


        if stop_requested():
            return False
        deadline = time.monotonic() + timeout_s
        for pub in self.node.publishers:
            try:
                left = max(0.001, deadline - time.monotonic())
                if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                    return False
            except Exception:  # a best-effort publisher has no acknowledgements to wait for
                continue
        return True

    def _poll(self) -> None:

        if self.done.done() or stop_requested() or (not self._checked_topics and not self._check_reader_topics()):
            return
        self._ticks += 1
        if self.open and not self._finishing and self._ticks % 10:
            return  # streaming: only keep track of who has come (seen), at a tenth of the rate
        self.present = self._matched() if self.readers else set()
        self.seen |= self.present
        now = time.monotonic()
        missing = self.missing()
        if not self.open:
            if missing:
                self._matched_since = None
            else:
                self._matched_since = self._matched_since or now
                if now - self._matched_since >= self.settle_s:
                    self.open = True
                    if not self._finishing:
                        self._waiting_since = None
                    self.node.get_logger().info(f"readers matched: {', '.join(self.readers)}")
                    if self.health is not None and self.health.message.startswith("waiting for readers"):
                        self.health.level, self.health.message = DiagnosticStatus.OK, "ok"
                    if self.on_open is not None:
                        self.on_open()
        if self._finishing and not missing and self.history_released() and self._acknowledged():
            self.done.set_result(True)
            return
        if missing and self._waiting_since is not None:
            self._report_missing(missing, now)

    def history_released(self) -> bool:
        """Every stream in ``keep_history_until`` has ended (its readers need the history no more)."""
        return set(self.keep_until) <= self.streams_ended

    def _report_missing(self, missing: list[str], now: float) -> None:
        waited = now - self._waiting_since
        what = "to acknowledge its final outputs" if self._finishing else "to match before its data goes out"
        topics = ", ".join(sorted({p.topic_name for p in self.publishers}))
        if waited >= self.wait_s:
            msg = (f"declared readers {', '.join(missing)} never matched {topics} (waited {waited:.0f} s "
                   f"{what}; parameter {READERS}: {self.readers}); failing rather than sending to nobody")
            self.node.get_logger().error(msg)
            if self.health is not None:
                self.health.error(msg)
            self.exit_code = 1
            self.node.exit_code = 1  # run_node's exit code
            self.done.set_result(False)
        elif now - self._last_log >= self.log_every_s and waited >= 1.0:
            self._last_log = now
            msg = f"waiting for readers {', '.join(missing)} {what} ({waited:.0f} of {self.wait_s:g} s)"
            self.node.get_logger().info(msg)
            if self.health is not None:
                self.health.warn(msg)


def streams_published_by(node_name: str) -> set[str]:
    """The vibro/status streams ``node_name`` announces (its topics' last name components)."""
    return topics.status_streams(t.name for t in topics.ALL_TOPICS if node_name in t.nodes)


class WriterWatch:
    """A sink's inputs have ended (looked at each time the owner calls :meth:`poll`, from a timer of its own): every
    declared writer (parameter ``writers``) has been seen publishing on ``topic_names`` (this node's namespace) and
    all of them have left since. Writers wait for their
    declared readers' acknowledgements before they exit, so by then everything has arrived in DDS; ``done``
    completes (when ``exit_when_done``) once this node's callbacks have also taken every writer's
    end-of-stream statuses and every item they announced (``received``), ``drain_s`` after the writers left
    at the earliest, ``grace_s`` at the latest (then with a warning naming what did not come).

    The ROS graph view is DDS discovery, which can lag or miss a change under load, so the writers'
    end-of-stream statuses (vibro/status) also count: a writer never listed whose streams all ended is taken
    as gone at once; a writer still listed ``stale_after_s`` after the last stream ended, with every item the
    streams announced received (``received``: items received per stream, None for a stream this node does
    not take), is taken as gone too (a stale
    listing: seen in a CI run, the recorder waited over 60 s after every writer had exited). Both are logged
    as warnings; the graph runner's count check (recorded vs announced) still follows."""

    REPORT_EVERY_S = 5.0

    def __init__(self, node: Node, topic_names: Sequence[str], *, drain_s: float = 0.5,
                 stale_after_s: float = 15.0, received: Callable[[str], int | None] | None = None,
                 grace_s: float = 5.0):

        writers = declare(node, "writers", [""], "node names whose outputs this node takes; it exits once all "
                          "have come and gone (with exit_when_done)")
        self.writers = sorted({str(w).strip() for w in writers if str(w).strip()})
        self.stale_after_s = float(declare(
            node, "stale_listing_s", float(stale_after_s), "s after every writer's streams ended (all announced "
            "items received) after which writers still listed in the ROS graph are taken as gone (a stale "
            "discovery view)"))
        if not self.stale_after_s > 0:

            raise RecordingError(f"{node.get_name()}: parameter 'stale_listing_s' must be > 0 s, "
                                 f"got {self.stale_after_s}")
        _, _, self.exit_when_done = declare_readiness_parameters(node)
        self.node = node
        self.topic_names = [node.resolve_topic_name(t) for t in topic_names]
        self.drain_s = drain_s
        self.grace_s = grace_s
        self.received = received
        self.seen: set[str] = set()
        self.done = Future()
        self.exit_code = 0
        self._ended_at: float | None = None
        self._run_id = run_id_parameter(node)
        self.finished_streams: set[str] = set()
        self.announced: dict[str, int] = {}  # stream -> items its final status announced
        self.streams_of = {w: streams_published_by(w) for w in self.writers}
        self._unlisted_logged: set[str] = set()
        self._all_ended_at: float | None = None
        self._last_report: float | None = None
        self._stale_logged = False
        self.active = bool(self.writers and self.exit_when_done)
        if self.active:
            results_subscription(node, StreamStatus, topics.STATUS.name, self._on_status)

    def _on_status(self, msg: StreamStatus) -> None:
        if msg.finished and (not self._run_id or not msg.run_id or msg.run_id == self._run_id):
            stream = str(msg.stream)
            self.finished_streams.add(stream)
            self.announced[stream] = max(self.announced.get(stream, 0), int(msg.items_sent))

    def _ended_unlisted(self) -> set[str]:
        """Writers never listed in the graph whose every stream has announced its end."""
        out = {w for w in self.writers if w not in self.seen and self.streams_of[w]
               and self.streams_of[w] <= self.finished_streams}
        for w in sorted(out - self._unlisted_logged):
            self.node.get_logger().warning(
                f"{w} never appeared in this node's ROS graph view, but its streams ended "
                f"({', '.join(sorted(self.streams_of[w]))}): taken as gone")
            self._unlisted_logged.add(w)
        return out

    def present(self) -> set[str]:
        ns = self.node.get_namespace()
        return {i.node_name for t in self.topic_names for i in self.node.get_publishers_info_by_topic(t)
                if i.node_namespace == ns and i.node_name in self.writers}

    def missing_items(self) -> dict[str, tuple[int, int]]:
        """Stream -> (received, announced) for the ended streams with fewer items received than announced
        (empty without a ``received`` counter: nothing to compare)."""
        if self.received is None:
            return {}
        counts = {s: (self.received(s), n) for s, n in self.announced.items()}
        return {s: c for s, c in counts.items() if c[0] is not None and c[0] < c[1]}

    def poll(self) -> None:
        """Look at the writers once: the owner calls it from its own timer (every 0.1 s: the recorder's), as
        a timer of its own would cost the node's executor another wake-up per period."""
        if not self.active or self.done.done():
            return
        now = time.monotonic()
        now_present = self.present()
        self.seen |= now_present
        all_ended = bool(self.writers) and all(self.streams_of[w] <= self.finished_streams for w in self.writers)
        self._all_ended_at = (self._all_ended_at or now) if all_ended else None
        if now_present and self._stale(now_present, now):
            now_present = set()
        if (self.seen | self._ended_unlisted()) >= set(self.writers) and not now_present:
            self._ended_at = self._ended_at or now
            # every end-of-stream status and announced item taken (not only sent: callbacks may still be
            # queued in this node), or the grace for them is over
            complete = self._all_ended_at is not None and not self.missing_items()
            if (complete and now - self._ended_at >= self.drain_s) or now - self._ended_at >= self.grace_s:
                if not complete:
                    self._warn_incomplete()
                self.node.get_logger().info(f"inputs ended: {', '.join(self.writers)} came and went")
                self.done.set_result(True)
        else:
            self._ended_at = None
            self._report_waiting(now_present, now)

    def _missing_text(self) -> str:
        """The missing items as "stream received of announced; ..." ("" when none)."""
        return "; ".join(f"{s} {got} of {n}" for s, (got, n) in sorted(self.missing_items().items()))

    def _warn_incomplete(self) -> None:
        silent = sorted(w for w in self.writers if not self.streams_of[w] <= self.finished_streams)
        short = self._missing_text()
        self.node.get_logger().warning(
            f"the writers left {self.grace_s:g} s ago"
            + (f"; no end-of-stream status from {', '.join(silent)}" if silent else "")
            + (f"; items received of those announced: {short}" if short else "") + ": ending with what came")

    def _stale(self, listed: set[str], now: float) -> bool:
        """Whether the writers still ``listed`` are a stale listing: every stream ended ``stale_after_s`` ago
        and every announced item received."""
        if self._all_ended_at is None or now - self._all_ended_at < self.stale_after_s or self.missing_items():
            return False
        if not self._stale_logged:
            self._stale_logged = True
            self.node.get_logger().warning(
                f"{', '.join(sorted(listed))} still listed as publishing {now - self._all_ended_at:.0f} s after "
                "every input stream ended with all announced items received: taken as gone (a stale ROS graph "
                "view)")
        return True

    def _report_waiting(self, listed: set[str], now: float) -> None:
        """Every ``REPORT_EVERY_S`` once every writer's streams have ended, say which writers this node still
        waits for and why (still listed as publishing, never seen, items not received)."""
        if self._all_ended_at is None:
            return
        last = self._last_report or self._all_ended_at
        if now - last < self.REPORT_EVERY_S:
            return
        self._last_report = now
        unseen = sorted(set(self.writers) - self.seen)
        short = self._missing_text()
        self.node.get_logger().warning(
            f"every input stream announced its end {now - self._all_ended_at:.0f} s ago; still listed as "
            f"publishing: {', '.join(sorted(listed)) or 'none'}; never seen: {', '.join(unseen) or 'none'}"
            + (f"; items not received yet: {short}" if short else ""))
