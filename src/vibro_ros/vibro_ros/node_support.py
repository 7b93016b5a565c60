"""What every vibro node shares: QoS profiles, declared parameters, diagnostics, clean shutdown.

This is the only vibro_io module that imports rclpy; the algorithm modules never do.
"""

from __future__ import annotations

import os
import signal
import time
from typing import Any, Callable

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from std_msgs.msg import Header

from vibro_model.errors import RecordingError
from vibro_msgs.msg import StreamStatus

from . import topics
from .dds_profile import use_vibro_dds_profile
from .lab_clock import TIME_ORIGIN_PARAMETER
from .node_help import handle_command_line, parameter_type_name

#: Data streams: reliable, deep queue; senders also apply credit-based flow control
#: (frame_source waits for the tracker's acknowledgements), so nothing is dropped.
STREAM_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                        reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
#: Results: reliable and transient-local, so a recorder or fitter that joins late still gets them.
#: Publishers use it as is; subscribers use :func:`vibro_ros.adaptive_qos.results_subscription`,
#: which also hears a volatile or best-effort publisher of the topic (a replay tool, a driver):
#: a transient-local reader alone rejects those, and rmw's BEST_AVAILABLE durability, fixed when
#: the subscription is created, turns transient local in a fresh process and rejects them too.
RESULTS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                         reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: A live camera driver's image_raw (best effort, shallow).
SENSOR_QOS = qos_profile_sensor_data

#: Items a latched history keeps by default: 100 s of frames at 1000 frames/s, 2000 s of 20 ms blocks.
HISTORY_DEPTH = 100_000


def history_qos(depth: int = HISTORY_DEPTH) -> QoSProfile:
    """A latched history (vibro/dic, vibro/accel): reliable, transient local, KEEP_LAST ``depth``.

    The publisher keeps its last ``depth`` items while it runs, so a node (re)started mid-run
    receives every item again, from the first, before the live ones. Both sides use the same
    depth (a reader's queue must hold the whole history too). A transient-local reader does not
    match a volatile publisher: publishers of these topics must use this profile.
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


HISTORY_QOS = history_qos()


def sensor_qos(depth: int) -> QoSProfile:
    """The sensor data profile (best effort, volatile, keep last) of a camera's image_raw with a reader queue of
    ``depth`` items: compatible with any driver's publisher, and holding ``depth`` images while the reader is
    busy."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth), reliability=SENSOR_QOS.reliability,
                      durability=SENSOR_QOS.durability)

#: ROS defaults (reliable, volatile, depth 10), e.g. /diagnostics as every ROS tool publishes it.
DEFAULT_QOS = QoSProfile(depth=10)

QOS_BY_KIND = {"stream": STREAM_QOS, "results": RESULTS_QOS, "sensor": SENSOR_QOS, "default": DEFAULT_QOS,
               "history": HISTORY_QOS}


def declare(node: Node, name: str, default: Any, description: str, read_only: bool = True) -> Any:
    """Declare a parameter with a description and return its value, of the default's type.

    The value a user gives (``-p``, a params file, launch) is checked here rather than by rclpy, whose type
    errors are a crash trace: an integer is taken for a float parameter (``end_wait_s:=5``), an empty list
    (``readers:=[]``, which reaches ROS without a type) for an empty list, and anything else of the wrong
    type is a :class:`vibro_model.errors.RecordingError` naming the node, the parameter, what it takes and what
    it got (one line, exit code 2 from :func:`run_node`)."""
    node.declare_parameter(name, default, ParameterDescriptor(description=description, read_only=read_only,
                                                              dynamic_typing=True))
    return parameter_of_type(node.get_name(), name, node.get_parameter(name).value, default)


def parameter_of_type(node_name: str, name: str, value: Any, default: Any) -> Any:
    """``value`` of parameter ``name`` as the type of its ``default`` (see :func:`declare`), or RecordingError
    naming the types as ``--help`` does (:func:`vibro_ros.node_help.parameter_type_name`)."""
    def refuse(hint: str = "") -> RecordingError:
        got = "no value" if value is None else f"{value!r} ({parameter_type_name(value)})"
        wanted = parameter_type_name(default)
        article = "an" if wanted[0] in "aeiou" else "a"
        return RecordingError(f"{node_name}: parameter '{name}' takes {article} {wanted}, got {got}{hint}")

    if isinstance(default, (list, tuple)):
        if value is None:  # an empty list has no type on the command line or in YAML
            return []
        if not isinstance(value, (list, tuple)):
            raise refuse()
        if not len(default):
            return list(value)
        try:
            return [parameter_of_type(node_name, name, v, default[0]) for v in value]
        except RecordingError:
            raise refuse() from None
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        raise refuse()
    if isinstance(default, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise refuse()
    if isinstance(default, float):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise refuse()
    if isinstance(default, str):
        if isinstance(value, str):
            return value
        raise refuse(" (quote a number meant as text: name:=\"'123'\")")
    return value


def run_id_parameter(node: Node) -> str:
    """The node's ``run_id`` parameter (declared on first use): the id ``vibro graph``/``vibro replay`` give
    every node of one run; the node stamps it on its StreamStatus/DicFrame/AccelBlock messages and refuses
    other runs' messages (vibro_ros.guard). Empty (a node started by hand) = no run id, accept any."""
    if not node.has_parameter("run_id"):
        declare(node, "run_id", "", "id of the run this node belongs to (set by vibro graph/replay); "
                "messages of another run stop the node. Empty: accept any run")
    return str(node.get_parameter("run_id").value)


def history_depth_parameter(node: Node) -> int:
    """The node's ``history_depth`` parameter (declared on first use): items kept by the latched histories of
    vibro/dic and vibro/accel (:func:`history_qos`); RecordingError unless >= 1."""
    if not node.has_parameter("history_depth"):
        declare(node, "history_depth", HISTORY_DEPTH,
                "items the latched histories of vibro/dic and vibro/accel keep for a node restarted mid-run "
                "(publisher and readers alike; vibro graph sets it from the recording's length)")
    depth = int(node.get_parameter("history_depth").value)
    if depth < 1:
        raise RecordingError(f"{node.get_name()}: parameter 'history_depth' must be >= 1, got {depth}")
    return depth


def cpu_nice_parameter(node: Node) -> int:
    """Declare ``cpu_nice`` and raise this process's nice value by it (0 = unchanged; at most 19). Any user may
    lower their own process's priority. Live, the nodes that read reliable, buffered streams (the fitter, the
    impact detector) give way to dic_tracker: its best-effort camera images are lost while it waits for a core,
    while theirs only wait in a queue."""
    nice = int(declare(node, "cpu_nice", 0, "raise this process's nice value by this much at start (0-19; live: "
                                           "the buffered nodes give the camera's tracker the cores first)"))
    if not 0 <= nice <= 19:
        raise RecordingError(f"{node.get_name()}: parameter 'cpu_nice' must be 0 to 19, got {nice}")
    if nice:
        os.nice(nice)
    return nice


def time_origin_parameter(node: Node) -> int:
    """The node's ``time_origin_unix_ns`` parameter (declared on first use): the lab-clock origin of its
    header stamps (:mod:`vibro_ros.lab_clock`: stamp = origin + data time, ns since the Unix epoch).
    ``vibro graph``/``vibro replay`` set it for every node; 0 (a node started by hand without it) keeps
    stamps on the data clock, which the node says once in its log. RecordingError when negative."""
    if not node.has_parameter(TIME_ORIGIN_PARAMETER):
        declare(node, TIME_ORIGIN_PARAMETER, 0,
                "wall time (ns since the Unix epoch) of data time 0: header stamps = it + camera/DAQ time "
                "(vibro graph sets it: rig.yaml camera.start_time_unix_s or the start of the run); "
                "0 = stamps are the data time itself")
        origin = int(node.get_parameter(TIME_ORIGIN_PARAMETER).value)
        if origin < 0:
            raise RecordingError(f"{node.get_name()}: parameter '{TIME_ORIGIN_PARAMETER}' must be >= 0 "
                                 f"(ns since the Unix epoch), got {origin}")
        if origin == 0:
            node.get_logger().info(f"parameter '{TIME_ORIGIN_PARAMETER}' not set: header stamps are the data "
                                   "time (camera/DAQ s), not the lab's wall clock")
    return int(node.get_parameter(TIME_ORIGIN_PARAMETER).value)


def stamp_from_seconds(header: Header, t_s: float, origin_ns: int = 0) -> Header:
    """Set ``header.stamp`` to data time ``t_s`` seconds (camera or DAQ time) on the lab clock: ``origin_ns``
    (:func:`time_origin_parameter`) + ``t_s``, rounded to the nearest ns, in integer ns
    (:func:`vibro_ros.lab_clock.stamp_ns_from_data_time`).

    A fraction that rounds up to a whole second carries into ``sec`` (0.9999999999 s is 1 s 0 ns,
    not 0 s 0 ns, which would put the item one second early).
    """
    from .lab_clock import NS_PER_S, stamp_ns_from_data_time

    header.stamp.sec, header.stamp.nanosec = divmod(stamp_ns_from_data_time(origin_ns, t_s), NS_PER_S)
    return header


def stamp_ns(header: Any) -> int:
    """``header.stamp`` as integer ns (any object with ``stamp.sec``/``stamp.nanosec``, e.g. from a bag)."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def seconds_from_stamp(header: Any, origin_ns: int = 0) -> float:
    """The data time (s) of ``header.stamp`` on the lab clock of ``origin_ns`` (inverse of
    :func:`stamp_from_seconds` to within 0.5 ns)."""
    from .lab_clock import data_time_from_stamp_ns

    return data_time_from_stamp_ns(origin_ns, stamp_ns(header))


class Health:
    """Counts and rates a node reports on /diagnostics once a second, and once more when it stops
    (:func:`run_node`). /diagnostics is absolute: it stays at the root under a namespace. Its ``pid`` value
    (the process id) tells a bag's reader that a node was restarted (two pids under one node name)."""

    def __init__(self, node: Node, hardware_id: str = "vibro"):
        self._node = node
        self._hardware_id = hardware_id
        self.counters: dict[str, int] = {}
        self.values: dict[str, float | str] = {"pid": str(os.getpid())}
        self.level = DiagnosticStatus.OK
        self.message = "ok"
        self._start = time.monotonic()
        self._last_count = 0
        self._last_time = self._start
        self.rate_counter = "processed"
        self._first: tuple[float, float] | None = None  # (monotonic s, data stamp s) of the first item
        self._last: tuple[float, float] | None = None
        self._pub = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS.name, 10)
        node.create_timer(1.0, self.publish)

    def count(self, key: str, n: int = 1) -> None:
        self.counters[key] = self.counters.get(key, 0) + n

    def observe(self, stamp_s: float) -> None:
        """Note that an item stamped ``stamp_s`` (data clock: camera or DAQ time, s) was just processed.

        Reported as ``lag_s`` = wall time elapsed between the first and the latest item minus
        the data time elapsed between them: 0 when the node keeps pace with the data's own
        clock (real time), growing by (1 - rate/real-time rate) s per s when it falls behind,
        negative when it runs faster (replay as fast as possible).
        """
        now = time.monotonic()
        if self._first is None:
            self._first = (now, stamp_s)
        self._last = (now, stamp_s)

    @property
    def lag_s(self) -> float:
        """Lag behind the data clock (see :meth:`observe`); NaN before the first item."""
        if self._first is None or self._last is None:
            return float("nan")
        return (self._last[0] - self._first[0]) - (self._last[1] - self._first[1])

    def warn(self, message: str) -> None:
        self.level = max(self.level, DiagnosticStatus.WARN)
        self.message = message

    def error(self, message: str) -> None:
        self.level = DiagnosticStatus.ERROR
        self.message = message

    def publish(self) -> None:
        now = time.monotonic()
        n = self.counters.get(self.rate_counter, 0)
        rate = (n - self._last_count) / max(now - self._last_time, 1e-9)
        self._last_count, self._last_time = n, now
        status = DiagnosticStatus(level=self.level, name=self._node.get_fully_qualified_name(),
                                  message=self.message, hardware_id=self._hardware_id)
        values = {f"{k}_count": str(v) for k, v in self.counters.items()}
        values["rate_hz"] = f"{rate:.1f}"
        values["lag_s"] = f"{self.lag_s:.4f}"
        values.update({k: str(v) for k, v in self.values.items()})
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(msg)


class StatusPublisher:
    """Publishes :class:`StreamStatus` for one stream (items sent/lost, finished).

    :meth:`publish` may be called as often as the node likes (a source calls it on every tick): a status
    equal to the last one published is not sent again, and progress (not finished) goes out at most every
    ``min_interval_s`` (the latest value, at the next call or the next repeat); every reader of vibro/status
    deserializes each one. A finished status goes out at once, and is repeated every second, so a subscriber
    whose queue overflowed or that matched late still learns that the stream has ended.
    """

    def __init__(self, node: Node, stream: str, min_interval_s: float = 0.1):
        if stream not in topics.STATUS_STREAMS:
            raise ValueError(f"StatusPublisher: unknown stream {stream!r} (vibro_ros.topics.STATUS_STREAMS)")
        self._node = node
        self._stream = stream
        self._min_interval_s = min_interval_s
        self._last: tuple[int, int, bool] | None = None  # last published
        self._pending: tuple[int, int, bool] | None = None  # newest value, not yet published
        self._last_time = -float("inf")
        self._run_id = run_id_parameter(node)
        self._pub = node.create_publisher(StreamStatus, topics.STATUS.name, RESULTS_QOS)
        node.create_timer(1.0, self._repeat)

    def publish(self, sent: int, lost: int, finished: bool) -> None:
        value = (int(sent), int(lost), bool(finished))
        if value == self._last:
            self._pending = None
            return
        if finished or time.monotonic() - self._last_time >= self._min_interval_s:
            self._send(value)
        else:
            self._pending = value

    def _send(self, value: tuple[int, int, bool]) -> None:
        self._last, self._pending, self._last_time = value, None, time.monotonic()
        sent, lost, finished = value
        msg = StreamStatus(stream=self._stream, items_sent=sent, items_lost=lost, finished=finished,
                           run_id=self._run_id)
        msg.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(msg)

    def _repeat(self) -> None:
        if self._pending is not None:
            self._send(self._pending)
        elif self._last is not None and self._last[2]:
            self._send(self._last)


def flush_publishers(node: Node, timeout_s: float = 3.0) -> list[str]:
    """Wait (bounded) until subscribers acknowledged what this node published, so that a node that
    ends by itself does not take its last messages (e.g. an end-of-stream status) with it. Returns the
    topics still unacknowledged after ``timeout_s`` (also logged: what a reader may have missed)."""
    from rclpy.duration import Duration

    deadline = time.monotonic() + timeout_s
    unacknowledged = []
    for pub in list(node.publishers):
        try:
            if not pub.wait_for_all_acked(Duration(seconds=max(0.0, deadline - time.monotonic()))):
                unacknowledged.append(pub.topic_name)
        except Exception:  # best effort: a publisher without reliable readers has nothing to wait for
            pass
    if unacknowledged:
        node.get_logger().warning(f"exiting with messages not acknowledged after {timeout_s:g} s on "
                                  f"{', '.join(sorted(set(unacknowledged)))} (a reader may have missed them)")
    return unacknowledged


#: Executors a node can spin in (environment variable ``VIBRO_EXECUTOR``). ``events`` (rclpy's
#: EventsExecutor, C++) halves the graph's CPU per frame against the SingleThreadedExecutor
#: (bench/bench_graph.py measures both, per node); ``single`` is the conservative fallback.
EXECUTORS = ("events", "single")


def make_executor(default: str = "events"):
    """The executor named by ``VIBRO_EXECUTOR``, else ``default`` (a node class's ``EXECUTOR``);
    RecordingError for an unknown name."""
    kind = os.environ.get("VIBRO_EXECUTOR", "") or default
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    if kind == "single":
        from rclpy.executors import SingleThreadedExecutor

        return SingleThreadedExecutor()
    raise RecordingError(f"VIBRO_EXECUTOR={kind!r}: must be one of {', '.join(EXECUTORS)}")


def spin_until_done(executor, done=None, slice_s: float = 0.5) -> None:
    """Spin until ``done`` (an ``rclpy.task.Future``; None = forever) completes or rclpy shuts down.

    Spins in bounded slices: rclpy 7.1's EventsExecutor never returns from ``spin()`` or from
    ``spin_until_future_complete`` without a timeout once SIGINT has shut the context down.
    """
    from rclpy.task import Future

    done = done if done is not None else Future()
    while rclpy.ok() and not done.done() and not stop_requested():
        executor.spin_until_future_complete(done, timeout_sec=slice_s)


_stop_signals: list[int] = []


def _note_stop(signum: int, _frame) -> None:
    """The SIGINT/SIGTERM handler: remember the stop (the spin loop ends within one slice) instead of
    raising KeyboardInterrupt in the middle of a callback. rclpy's own handlers are not installed: after
    the first signal they leave SIGINT at its default action, so a second SIGINT (Ctrl-C to the process
    group plus launch's own SIGINT) killed the node (exit code -2 in ros2 launch)."""
    _stop_signals.append(signum)


def stop_requested() -> bool:
    """A SIGINT or SIGTERM has been received by this process."""
    return bool(_stop_signals)


def run_node(factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """Init rclpy, spin the node until SIGINT/SIGTERM or until it is done, then shut down cleanly.

    A node that ends by itself has a ``done`` attribute (an ``rclpy.task.Future``) and sets
    its result; its ``exit_code`` attribute (default 0) is then the exit code. Bad input raised while
    building the node (``RecordingError``), or set as the exception of ``done`` (foreign input,
    vibro_ros.guard), is logged as one line and gives exit code 2. SIGINT/SIGTERM: exit code 0.
    ``--help`` (before ``--ros-args``) prints the node's usage and gives 0 without starting it; any other
    non-ROS argument gives 2 (``node_help``). ``factory`` is the node class (its source gives the usage).
    """
    import sys

    from rclpy.signals import SignalHandlerOptions

    argv = list(sys.argv if args is None else args)
    handled = handle_command_line(factory, argv) if isinstance(factory, type) else None
    if handled is not None:
        return handled

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _note_stop)
    use_vibro_dds_profile()  # acknowledgements in 0.1 s, so the node's end-of-stream wait is short
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = executor = None
    code = 0
    try:
        node = factory()
        # the executor stays referenced here until the node is destroyed below (as it did before this loop was a
        # function of its own): dropped earlier, a node's destroy_node was seen spinning at 75 % CPU for minutes
        executor = make_executor(getattr(node, "EXECUTOR", "events"))
        code = _spin_node(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RecordingError as exc:
        rclpy.logging.get_logger("vibro").error(str(exc))
        code = 2
    except Exception:
        if rclpy.ok() and not stop_requested():
            raise
        # a callback that ran while SIGINT/SIGTERM was shutting the context down: clean stop
    finally:
        cleanup_from = time.monotonic()
        name = node.get_fully_qualified_name() if node is not None else ""
        if node is not None:  # a stop signal during this cleanup is only noted (_note_stop), never raised
            if executor is not None:
                _release_from_executor(executor, node)
            _close_node(node)
        if rclpy.ok():
            rclpy.shutdown(uninstall_handlers=False)  # uninstalling what was never installed: SIGINT -> SIG_DFL
        if name:  # when it left the ROS graph, for a reader of the logs (its peers' view of it may lag)
            print(f"[{time.time():.6f}] {name}: left the ROS graph with exit code {code} "
                  f"(cleanup {time.monotonic() - cleanup_from:.2f} s)", file=sys.stderr, flush=True)
        if _RETAINED_AT_EXIT is not None:  # a node process that ends with os._exit: see keep_node_objects_until_exit
            _RETAINED_AT_EXIT.extend(x for x in (node, executor) if x is not None)
    for sig in (signal.SIGINT, signal.SIGTERM):
        # the node has stopped; the interpreter's finalisation resets Python handlers to SIG_DFL (not SIG_IGN),
        # so a second Ctrl-C arriving now would still kill the process with -2
        signal.signal(sig, signal.SIG_IGN)
    return code


#: what :func:`run_node` keeps referenced until the process ends (:func:`keep_node_objects_until_exit`)
_RETAINED_AT_EXIT: list | None = None


def keep_node_objects_until_exit() -> None:
    """In a node's own process, which ends with ``os._exit`` (vibro_ros.entry.exit_now): keep the node and its
    executor referenced after :func:`run_node` returns, so that their C++ destructors never run on a shut-down
    context. Once under load a simulator that had logged "left the ROS graph with exit code 0" was still alive
    150 s later, ignoring SIGINT (a loaded make test, tests/test_graph_faults.py); what ran after that line were
    run_node's return, which frees them, and exit_now. The node itself is taken out of the executor and destroyed
    before the context shuts down (:func:`_release_from_executor`); what is kept is what is left of them. Not in
    a process that goes on (a test calling a node's main): there the objects are freed as before."""
    global _RETAINED_AT_EXIT
    if _RETAINED_AT_EXIT is None:
        _RETAINED_AT_EXIT = []


def _spin_node(node: Node, executor) -> int:
    """Spin ``node`` on ``executor`` until it is done (or stopped); its exit code. The exception set on its
    ``done`` future is raised. The caller keeps ``executor`` until the node is destroyed."""
    executor.add_node(node)
    done = getattr(node, "done", None)
    spin_until_done(executor, done)
    if done is not None and done.done() and done.exception() is not None:
        raise done.exception()  # e.g. vibro_ros.guard.ForeignInputError: one line, exit code 2
    return int(getattr(node, "exit_code", 0) or 0)


def _release_from_executor(executor, node: Node, timeout_s: float = 1.0) -> None:
    """Take ``node`` out of ``executor`` and shut the executor down, while the context is up, so that the node's
    ``destroy_node`` destroys it at once. An executor that still holds a node keeps its handle alive past
    ``destroy_node`` (rclpy destroys a handle when no longer in use), and with it the DDS participant: its peers
    then see it leave only when its lease expires (Fast DDS: 20 s), and every reliable writer with a reader in it
    waits that long for acknowledgements (a 300-frame vibro graph run took 47 s instead of 8 when the executor was
    kept until os._exit)."""
    try:
        executor.remove_node(node)
        executor.shutdown(timeout_sec=timeout_s)
    except Exception:  # best effort: the context may be going down (a stop signal); destroy_node still runs
        pass


def _close_node(node: Node) -> None:
    """Close ``node`` (its ``close``), publish its final health and flush its publishers while the context is
    up, then destroy it."""
    close = getattr(node, "close", None)
    if close is not None:
        close()
    if rclpy.ok():
        health = getattr(node, "health", None)
        if isinstance(health, Health):  # the final counts, also of a node that ran < 1 s
            try:
                health.publish()
            except Exception:  # best effort, like the flush below: the context may be going down
                pass
        flush_publishers(node)
    node.destroy_node()
