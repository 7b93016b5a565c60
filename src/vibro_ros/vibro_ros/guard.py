"""Foreign input: a node stops rather than merge another run's (or another publisher's) data into its own.

Two ``vibro graph`` runs on one machine, a hand-started node, a camera left publishing: on a shared
DDS domain their messages reach every subscriber of the same topic name, and a node that merged them
would publish numbers of no run at all with exit code 0. :class:`InputGuard` checks, from the node's
subscription callbacks and a timer:

(a) publishers: an input topic that has a single publisher in the topic table (vibro/frames, vibro/dic,
    vibro/accel, the fitter's results) shows more than one publishing node; or, in a run started by
    ``vibro graph``/``vibro replay`` (``run_id`` set), a publishing node other than the expected one;
(b) order: an index that repeats or goes back on a stream (a second frame 17, frame 16 after frame 17),
    or a latched history that does not begin where the stream began (a node restarted after the
    publisher's history was lost: it would silently work on the rest only);
(c) run id: a StreamStatus, DicFrame or AccelBlock that carries another run's id.

The first violation stops the node: from then on every message is ignored, and a
:class:`ForeignInputError` naming the topic and its publishers is set on the node's ``done`` future
(for (b) and (c) once the publisher of the offending message is known by name: at least ``name_wait_s``
later unless a new publisher was named sooner, until no discovered publisher of the topic is unnamed, and
at most ``name_wait_max_s`` later); ``node_support.run_node`` logs it as one line and exits with code 2, and
``vibro graph`` fails the run with that line. Imports rclpy.
"""

from __future__ import annotations

import time

from rclpy.node import Node
from rclpy.task import Future

from vibro_model.errors import RecordingError

from .node_support import run_id_parameter
from .topics import Topic

#: Nodes that stand in for a topic table publisher: vibro replay's bag_source plays recorded frames and blocks.
SUBSTITUTES: dict[str, tuple[str, ...]] = {"frame_source": ("bag_source",), "accel_source": ("bag_source",)}


class ForeignInputError(RecordingError):
    """A node's input mixes in data that is not its run's."""


def expected_publishers(topic: Topic) -> tuple[str, ...]:
    """Node names allowed to publish ``topic`` in a vibro run: the topic table's publisher and its substitutes."""
    return (topic.publisher, *SUBSTITUTES.get(topic.publisher, ()))


def naming_settled(named_then: int, named_now: int, unnamed_now: int, waited_s: float, wait_s: float,
                   wait_max_s: float) -> bool:
    """Whether a stopping guard may name the publishers of the offending topic now.

    A DDS endpoint, and its messages, arrive before the name of its node (rmw reports ``_NODE_NAME_UNKNOWN_``
    until then; on a loaded machine for seconds): so not while a discovered publisher is unnamed, unless
    ``wait_max_s`` has passed; otherwise once a publisher more is named than when the violation was seen
    (``named_then``), or after ``wait_s`` (the offender may be the expected publisher itself).
    """
    if waited_s >= wait_max_s:
        return True
    return unnamed_now == 0 and (named_now > named_then or waited_s >= wait_s)


def _unknown(info) -> bool:
    return "_UNKNOWN_" in info.node_name or "_UNKNOWN_" in info.node_namespace


class InputGuard:
    """Checks one node's inputs; call :meth:`accept` first thing in every subscription callback.

    Declares the node's ``run_id`` parameter. Gives the node a ``done`` future if it has none (so that
    ``run_node`` stops it on the first violation) and checks the publishers of watched topics every
    ``check_period_s`` seconds.
    """

    def __init__(self, node: Node, check_period_s: float = 0.5, name_wait_s: float = 1.0,
                 name_wait_max_s: float = 10.0):
        self.node = node
        self.run_id = run_id_parameter(node)
        self.error: str | None = None
        self.name_wait_s = name_wait_s
        self.name_wait_max_s = name_wait_max_s
        self._pending: tuple[str, int, float] | None = None  # (topic, publishers seen then, monotonic s)
        self._watched: dict[str, tuple[str, tuple[str, ...]]] = {}  # resolved topic -> (table name, expected)
        self._last_index: dict[str, int] = {}
        self._fqn = node.get_fully_qualified_name()
        done = getattr(node, "done", None)
        if done is None:
            done = Future()
            node.done = done
        self._done: Future = done
        node.create_timer(check_period_s, self._on_timer)

    def _on_timer(self) -> None:
        if self._pending is not None:
            topic, seen, since = self._pending
            found, unnamed = self._publisher_names(topic)
            waited_s = time.monotonic() - since
            if naming_settled(seen, len(found), unnamed, waited_s, self.name_wait_s, self.name_wait_max_s):
                also = f"; {unnamed} more not known by name after {waited_s:.1f} s" if unnamed else ""
                self._stop(f"{self.error} (publishers of {topic}: {', '.join(found) or 'none known'}{also})")
            return
        self.check_publishers()

    # ------------------------------------------------------------------ (a) publishers
    def watch(self, topic: Topic) -> None:
        """Check the publishers of ``topic`` (one that has a single publisher in the topic table)."""
        self._watched[self.node.resolve_topic_name(topic.name)] = (topic.name, expected_publishers(topic))

    def publishers(self, topic_name: str) -> list[str]:
        """Fully qualified names of the nodes publishing ``topic_name`` (resolved), this node excluded."""
        return self._publisher_names(topic_name)[0]

    def _publisher_names(self, topic_name: str) -> tuple[list[str], int]:
        """(:meth:`publishers`, how many discovered publishers are not known by node name yet), from one query
        of the graph: an endpoint is discovered before its node's name (rmw reports _NODE_NAME_UNKNOWN_ until
        then)."""
        infos = self.node.get_publishers_info_by_topic(self.node.resolve_topic_name(topic_name))
        names = {f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos if not _unknown(i)}
        names.discard(self._fqn)
        return sorted(names), sum(1 for i in infos if _unknown(i))

    def check_publishers(self) -> bool:
        """(a) for every watched topic; False (and the node stopped) on a foreign publisher."""
        for resolved, (name, expected) in self._watched.items():
            if not self.ok():
                return False
            found = self.publishers(resolved)
            if len(found) > 1:
                self.fail(f"{name}: {len(found)} nodes publish it ({', '.join(found)}); a vibro run expects "
                          f"only {' or '.join(expected)}: another run or node is publishing on this topic")
            elif found and self.run_id:
                namespace = self.node.get_namespace().rstrip("/")
                allowed = {f"{namespace}/{n}" for n in expected}
                if found[0] not in allowed:
                    self.fail(f"{name}: unexpected publisher {found[0]} (this run expects "
                              f"{' or '.join(sorted(allowed))}): another run or node is publishing on this topic")
        return self.ok()

    # ------------------------------------------------------------------ (b), (c) per message
    def accept(self, topic_name: str, *, run_id: str | None = None, index: int | None = None,
               first_index: int | None = None, what: str = "item") -> bool:
        """True when a message may be used. ``run_id``: the message's run id (StreamStatus, DicFrame,
        AccelBlock); ``index``: its position on the stream, which must grow; ``first_index``: where the stream
        began, which the first message received must be (a latched history is complete). False once the
        guard has stopped the node: the callback then ignores the message."""
        if not self.ok():
            return False
        if run_id is not None and self.run_id and run_id != self.run_id:
            self.fail(f"{topic_name}: a message of run {run_id or '(none)'!r} reached this node of run "
                      f"{self.run_id!r}: another vibro run is publishing on this topic", topic_name)
            return False
        if index is None:
            return True
        index = int(index)
        last = self._last_index.get(topic_name)
        if last is None:
            if topic_name in {n for n, _ in self._watched.values()} and not self.check_publishers():
                return False
            if first_index is not None and index != int(first_index):
                self.fail(f"{topic_name}: the first {what} received is {index} but the stream began at {what} "
                          f"{int(first_index)}: {what}s {int(first_index)}..{index - 1} are missing (this node "
                          f"started after the publisher's history lost them: restarted after the publisher was, "
                          f"or history_depth too small); stopping rather than work on part of the run")
                return False
        elif index <= last:
            again = "received twice" if index == last else f"after {what} {last}"
            self.fail(f"{topic_name}: {what} {index} {again}: two publishers are merged on this topic "
                      "(another run?)", topic_name)
            return False
        self._last_index[topic_name] = index
        return True

    def ok(self) -> bool:
        return self.error is None

    def fail(self, message: str, topic_name: str | None = None) -> None:
        """Stop the node with ``message`` (once): ForeignInputError on its ``done`` future. With ``topic_name``,
        the message gets the topic's publishers, once one more is known by name than now (a message can
        arrive before its publisher's node name), or after ``name_wait_s``, and in either case once every
        discovered publisher is named (at most ``name_wait_max_s``); no message is accepted meanwhile."""
        if self.error is not None:
            return
        self.error = f"{self._fqn}: {message}"
        if topic_name is None:
            self._stop(self.error)
        else:
            self._pending = (topic_name, len(self.publishers(topic_name)), time.monotonic())

    def _stop(self, message: str) -> None:
        self.error = message
        self._pending = None
        done = getattr(self.node, "done", None) or self._done  # the node's current one (e.g. its ReaderGate's)
        if not done.done():
            done.set_exception(ForeignInputError(message))
