"""Run the vibro node graph from a recording or a bag, watch it, and check the bag it recorded.

Every node runs in its own OS process and talks over DDS. The nodes wait for their declared
readers by name and, the stream ended, exit by themselves (any start order works, as with
``ros2 launch``); :mod:`vibro_bringup.supervisor` starts them, restarts a processing node that
dies, and ends the run at once with its error when a node fails. An in-process monitor (a
declared reader of every node) watches the topics into a :class:`GraphSummary`: frames in /
tracked / lost (a lost frame is never silent), CORs, D per model, findings; the bag (read back
once the recorder has closed it) is checked against what each publisher announced: a topic with
messages missing fails the run.
Each run lives in its own namespace with its own run id (:mod:`vibro_bringup.isolation`), so two
runs on one domain never mix; a node that sees foreign input stops (exit code 2, not restarted) and
the run fails with its error. ``vibro graph`` and ``vibro replay`` (vibro_app) call :func:`execute_graph`.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterable

from vibro_bringup.graph_spec import (
    ALL_SPECS,
    DEFAULT_RUN_SETUP,
    MONITOR,
    VIEWER,
    NodeSpec,
    RunSetup,
    foxglove_layout_file,
    graph_nodes,
    node_parameters,
    run_time_origin,
    write_params_file,
)
from vibro_bringup.isolation import RunIdentity, new_run_identity
from vibro_bringup.supervisor import START_ORDER, Failure, Supervisor
from vibro_foxglove.view import websocket_url
from vibro_io.outputs import prepare_output_entries
from vibro_io.rig import load_rig, rig_checked_environment
from vibro_model.errors import RecordingError
from vibro_ros import topics


@dataclass(kw_only=True)
class GraphSummary:
    """What the monitor saw on the graph's topics."""

    frames_announced: int = 0
    frames_unreadable: int = 0
    dic_frames: int = 0
    dic_lost: int = 0
    lost_reasons: dict[str, int] = field(default_factory=dict)
    impacts: dict = field(default_factory=dict)  # index -> streamed ImpactEstimate
    final_impacts: dict = field(default_factory=dict)  # index -> final ImpactEstimate (replaces streamed)
    deviations: dict[str, float] = field(default_factory=dict)
    findings: list = field(default_factory=list)
    finished: dict[str, bool] = field(default_factory=dict)
    counts: dict[str, tuple[int, int]] = field(default_factory=dict)  # stream -> (items sent, items lost)
    dic_indices: set = field(default_factory=set)
    restarts: dict[str, int] = field(default_factory=dict)  # node -> times restarted mid-run
    accel_span_s: list = field(default_factory=list)  # [first, last] accelerometer sample time (DAQ clock, s)
    accel_impacts_s: dict = field(default_factory=dict)  # index -> accelerometer impact time (DAQ clock, s)
    camera: object = None  # rig.yaml's CameraConfig (frame times for the coverage note)
    failures: list[Failure] = field(default_factory=list)  # nodes that ended the run
    foxglove_url: str = ""  # the Foxglove WebSocket server of the run (empty: none)
    count_problems: list = field(default_factory=list)  # topics whose recorded count misses announced items
    recorded: dict = field(default_factory=dict)  # topic -> (announced, recorded)
    nodes: list = field(default_factory=list)  # the run's node names
    identity: str = ""  # run id, namespace and domain of the run


class Monitor:
    """An in-process node that watches the graph's topics (every node counts it as a declared reader)."""

    def __init__(self, summary: GraphSummary, recording: Path, identity: RunIdentity):
        import rclpy

        from vibro_msgs.msg import (
            AccelBlock,
            AccelImpact,
            DicFrame,
            DiscrepancyFinding,
            ImpactEstimate,
            SimulationResult,
            StreamStatus,
        )
        from vibro_ros.node_support import RESULTS_QOS, STREAM_QOS, make_executor

        s = self.summary = summary
        run_id = identity.run_id
        rclpy.init()
        self.node = node = rclpy.create_node(MONITOR, namespace=identity.namespace)
        self.executor = make_executor()
        self.executor.add_node(node)

        def on_status(m: StreamStatus) -> None:
            if m.run_id != run_id:  # another run's (its nodes stop this run with an error)
                return
            if m.stream == "frames":
                s.frames_announced = max(s.frames_announced, int(m.items_sent + m.items_lost))
                s.frames_unreadable = max(s.frames_unreadable, int(m.items_lost))
            s.counts[m.stream] = (int(m.items_sent), int(m.items_lost))
            if m.finished:
                s.finished[m.stream] = True

        def on_dic(m: DicFrame) -> None:
            if m.run_id != run_id or m.frame_index in s.dic_indices:
                return
            s.dic_indices.add(int(m.frame_index))
            s.dic_frames += 1
            if m.lost:
                s.dic_lost += 1
                reason = m.status or "lost"
                s.lost_reasons[reason] = s.lost_reasons.get(reason, 0) + 1

        node.create_subscription(StreamStatus, topics.STATUS.name, on_status, RESULTS_QOS)
        node.create_subscription(DicFrame, topics.DIC.name, on_dic, STREAM_QOS)
        node.create_subscription(ImpactEstimate, topics.IMPACTS.name,
                                 lambda m: (s.final_impacts if m.final else s.impacts).__setitem__(m.index, m),
                                 RESULTS_QOS)
        node.create_subscription(SimulationResult, topics.SIMULATION.name,
                                 lambda m: s.deviations.__setitem__(m.model, m.deviation), RESULTS_QOS)
        node.create_subscription(DiscrepancyFinding, topics.DISCREPANCY.name, s.findings.append, RESULTS_QOS)

        def on_block(m: AccelBlock) -> None:  # only the time span: frames that stop early are reported
            if m.run_id != run_id:
                return
            t0, t1 = m.t_start_s, m.t_start_s + (len(m.upper_ms2) - 1) / m.sample_rate_hz
            s.accel_span_s = [min(t0, s.accel_span_s[0]), max(t1, s.accel_span_s[1])] if s.accel_span_s else [t0, t1]

        node.create_subscription(AccelBlock, topics.ACCEL.name, on_block, RESULTS_QOS)
        node.create_subscription(AccelImpact, topics.ACCEL_IMPACTS.name,
                                 lambda m: s.accel_impacts_s.__setitem__(int(m.index), float(m.t_s)), RESULTS_QOS)
        try:
            s.camera = load_rig(Path(recording) / "rig.yaml").camera
        except (RecordingError, OSError):
            s.camera = None

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def subscribed(self, node_name: str, topic_names: Iterable[str]) -> bool:
        """Node ``node_name`` of this run's namespace has a subscription on every one of ``topic_names``
        (relative names, e.g. vibro/dic), as the ROS graph shows it to this node."""
        namespace = self.node.get_namespace()
        for topic in topic_names:
            infos = self.node.get_subscriptions_info_by_topic(self.node.resolve_topic_name(topic))
            if not any(i.node_name == node_name and i.node_namespace == namespace for i in infos):
                return False
        return True

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


@dataclass(frozen=True, kw_only=True)
class GraphRun:
    """How one run of the graph is started and watched (:func:`execute_graph`).

    Attributes
    ----------
    timeout_s : float
        Wall-clock limit of the run (s): what still runs then is stopped.
    env : dict
        The nodes' environment (:func:`prepare_environment`).
    respawn : int
        Restarts allowed per node.
    namespace : str or None
        The run's namespace (None: ``/vibro_<run id>``).
    history_depth : int or None
        Items the latched histories of vibro/dic and vibro/accel keep (None: the nodes' own).
    extra_params : dict or None
        ``{node: {parameter: value}}`` set over the run's parameters.
    reference : callable or None
        ``reference(folder)`` writes frame 0 as an image file into the run's temporary folder for dic_tracker's
        ``reference_image`` and returns its path (None: the run setup's ``reference_image``).
    """

    timeout_s: float
    env: dict[str, str]
    respawn: int = 2
    namespace: str | None = None
    history_depth: int | None = None
    extra_params: dict | None = None
    reference: Callable[[Path], Path | None] | None = None


def execute_graph(rig_dir: Path, bag: Path, sources: list[NodeSpec], *, with_accel: bool, run: GraphRun,
                  setup: RunSetup = DEFAULT_RUN_SETUP) -> tuple[bool, GraphSummary, Path]:
    """Run the graph (processing nodes, the recorder to ``bag``, ``sources``) until every node has exited by
    itself, a node fails, or ``run.timeout_s``; stop what still runs; check the bag's counts.

    ``rig_dir`` holds the rig.yaml (and, for the file sources, the recording). Returns
    (ok, summary, log folder). ``run`` (:class:`GraphRun`): the limit, environment, restarts, namespace,
    history depth, extra parameters and the reference frame's writer. The run gets a new run id and lives in
    ``run.namespace`` (default ``/vibro_<run id>``). ``setup`` (:class:`vibro_bringup.graph_spec.RunSetup`):
    the parameters file (``base``); ``time_origin_ns``: every node's ``time_origin_unix_ns``, the lab clock
    of the header stamps (default: rig.yaml's ``camera.start_time_unix_s``, else frame 0 = the wall clock now;
    graph_spec.run_time_origin); ``foxglove``: the Foxglove bridge's parameters (host, port) to run it too;
    its URL is printed at the start.
    """
    identity = new_run_identity(run.namespace)
    nodes = _run_nodes(sources, with_accel, foxglove=setup.foxglove is not None)
    summary = GraphSummary(nodes=[s.name for s in nodes])
    log_dir = bag.parent / f"{bag.name}.logs"
    log_dir.mkdir(exist_ok=True)
    if setup.time_origin_ns is None:
        setup = replace(setup, time_origin_ns=run_time_origin(rig_dir / "rig.yaml"))
    with tempfile.TemporaryDirectory(prefix="vibro-graph-") as tmp:
        ref_png = run.reference(Path(tmp)) if run.reference is not None else setup.reference_image
        setup = replace(setup, reference_image=ref_png)
        params = _run_parameters(rig_dir, bag, setup, with_accel, nodes, identity.run_id, run)
        params_file = write_params_file(params, Path(tmp) / "params.yaml")
        _announce(summary, identity.describe(run.env), setup, nodes)

        def command(spec: NodeSpec) -> list[str]:
            return [sys.executable, "-m", "vibro_bringup.child", spec.module, "--ros-args", "--params-file",
                    str(params_file), "-r", f"__node:={spec.name}", "-r", f"__ns:={identity.namespace}"]

        # the rig.yaml's warnings were said once, here (run_time_origin read it): not again by every node
        env = {**run.env, **rig_checked_environment(rig_dir / "rig.yaml")}
        supervisor = Supervisor(nodes, command, log_dir, env, run.respawn)
        ok = _supervise(supervisor, summary, rig_dir, identity, run.timeout_s)
    return _conclude(summary, supervisor, bag, ok), summary, log_dir


def _run_nodes(sources: list[NodeSpec], with_accel: bool, *, foxglove: bool) -> list[NodeSpec]:
    """The run's nodes: the node table's for a bag (with the accelerometers, the Foxglove bridge), its sources
    ``sources``; a node whose module this checkout lacks is left out, saying so."""
    replay = any(s.name == "bag_source" for s in sources)
    nodes = [s for s in graph_nodes(bag=True, with_accel=with_accel, replay=replay, foxglove=foxglove)
             if s.role != "source" or s in sources]
    missing = [s.name for s in nodes if not _importable(s.module)]
    if missing:
        print(f"vibro graph: nodes not available in this checkout: {', '.join(missing)}", file=sys.stderr)
        nodes = [s for s in nodes if s.name not in missing]
    return nodes


def _run_parameters(rig_dir: Path, bag: Path, setup: RunSetup, with_accel: bool, nodes: list[NodeSpec],
                    run_id: str, run: GraphRun) -> dict[str, dict]:
    """Every node's parameters for this run (:func:`vibro_bringup.graph_spec.node_parameters`, the monitor as an
    extra reader), with the run id, ``run.history_depth`` and ``run.extra_params`` over them."""
    params = node_parameters(rig_dir, bag, setup, with_accel, nodes=nodes, extra_readers=[MONITOR])
    for spec in nodes:  # one run: its id, and histories a restarted node can recover from
        params.setdefault(spec.name, {})["run_id"] = run_id
        if run.history_depth is not None:
            params[spec.name]["history_depth"] = int(run.history_depth)
    for node, values in (run.extra_params or {}).items():
        params.setdefault(node, {}).update(values)
    return params


def _announce(summary: GraphSummary, identity_line: str, setup: RunSetup, nodes: list[NodeSpec]) -> None:
    """Print (and keep in ``summary``) the run's identity, its stamps' clock and the Foxglove bridge's URL."""
    summary.identity = identity_line
    print(summary.identity, flush=True)
    print(f"stamps: {describe_origin(setup.time_origin_ns)}", flush=True)
    foxglove = setup.foxglove
    if foxglove is not None and any(s.name == "foxglove_bridge" for s in nodes):
        summary.foxglove_url = websocket_url(foxglove["host"], foxglove["port"])
        print(f"foxglove: {summary.foxglove_url} (open it in the Foxglove app: Open connection > Foxglove "
              f"WebSocket; layout: {foxglove_layout_file()})", flush=True)


def _supervise(supervisor: Supervisor, summary: GraphSummary, rig_dir: Path, identity: RunIdentity,
               timeout_s: float) -> bool:
    """Start the nodes (viewers first) and watch them until all have finished (True), one fails or
    ``timeout_s`` (s) passes (False, said on stderr); then stop what still runs."""
    ok = False
    monitor = None
    try:
        monitor = Monitor(summary, rig_dir, identity)
        deadline = time.monotonic() + timeout_s
        supervisor.start_all([VIEWER])
        viewers = [s for s in supervisor.specs.values() if s.role == VIEWER]
        failures = _wait_for_viewers(viewers, supervisor, monitor, deadline)
        if not failures:
            supervisor.start_all([r for r in START_ORDER if r != VIEWER])
        linger = Linger()
        while time.monotonic() < deadline:
            monitor.spin(0.05)
            failures = failures or supervisor.poll()
            if failures:
                for f in failures:
                    print(f"vibro graph: {f.describe()}", file=sys.stderr, flush=True)
                break
            if supervisor.all_finished():
                ok = True
                break
            if linger.over(supervisor.lingering({s for s, done in summary.finished.items() if done})):
                _stop_lingering(supervisor, linger)
                ok = True  # the run stands on what was recorded: _conclude checks the bag's counts
                break
        else:
            print(f"vibro graph: timeout after {timeout_s:g} s; still running: "
                  f"{', '.join(supervisor.running())}", file=sys.stderr)
    finally:
        supervisor.stop()
        if monitor is not None:
            monitor.spin(0.2)
            monitor.close()
    return ok


#: s a node may stay up once its streams have ended and every other node has finished, before it is stopped as hung
LINGER_S = 10.0


class Linger:
    """How long the same nodes have been lingering (:meth:`vibro_bringup.supervisor.Supervisor.lingering`)."""

    def __init__(self, limit_s: float = LINGER_S):
        self.limit_s = limit_s
        self.names: list[str] = []
        self._since = 0.0

    def over(self, names: list[str]) -> bool:
        """Whether ``names`` (the lingering nodes now) have lingered ``limit_s``; a change restarts the clock."""
        now = time.monotonic()
        if names != self.names:
            self.names, self._since = names, now
        return bool(names) and now - self._since >= self.limit_s


def _stop_lingering(supervisor: Supervisor, linger: Linger, grace_s: float = 5.0) -> None:
    """Stop the nodes ``linger`` names, whose work is over but which have not exited (hung), saying so with each
    one's threads' stacks."""
    for name in linger.names:
        supervisor.dump_stacks(name, wait_s=0.5)
        print(f"vibro graph: warning: {name} is still running {linger.limit_s:g} s after its streams ended and every "
              f"other node finished; stopping it (its threads' stacks are in {supervisor.logs[name]}); the results "
              "are those it published, checked against the bag below", file=sys.stderr, flush=True)
    supervisor.stop(grace_s=grace_s, names=linger.names)


def _conclude(summary: GraphSummary, supervisor: Supervisor, bag: Path, ok: bool) -> bool:
    """Put the restarts, failures and the bag's count problems into ``summary``; the run's verdict."""
    summary.restarts = dict(supervisor.restarts)
    summary.failures = list(supervisor.failures)
    summary.count_problems = check_recorded_counts(bag, summary)
    if not ok:
        waiting = sorted(supervisor.specs.keys() - supervisor.finished - {f.name for f in supervisor.failures})
        print("vibro graph: the graph did not finish; nodes not finished: "
              f"{', '.join(waiting) or 'none'}; the bag holds what was recorded", file=sys.stderr)
    return ok and not summary.count_problems


#: s a viewer may take to subscribe before the run starts without it on its first frames (it then says so)
VIEWER_READY_S = 60.0


def _wait_for_viewers(viewers: list[NodeSpec], supervisor: Supervisor, monitor: Monitor,
                      deadline: float) -> list[Failure]:
    """From a recording nothing waits for a viewer (the Foxglove bridge), yet its user wants to watch the run
    from its first frame: the other nodes start once each viewer subscribes to the streams it shows (vibro/frames,
    vibro/dic), after at most :data:`VIEWER_READY_S` without it, saying so. Returns the failures of the wait (a
    viewer that exited meanwhile): the run then ends before it started."""
    streams = (topics.FRAMES.name, topics.DIC.name)
    end = min(deadline, time.monotonic() + VIEWER_READY_S)
    waiting = list(viewers)
    while waiting and time.monotonic() < end:
        monitor.spin(0.05)
        failures = supervisor.poll()
        if failures:
            return failures
        waiting = [v for v in waiting if not monitor.subscribed(v.name, [t for t in streams if t in v.subscribes])]
    if waiting:
        print(f"vibro graph: {', '.join(v.name for v in waiting)} did not subscribe within {VIEWER_READY_S:g} s; "
              "the run starts without waiting for it (it may miss the first frames)", file=sys.stderr, flush=True)
    return []


def describe_origin(origin_ns: int) -> str:
    """One line on the lab clock of a run's header stamps (origin as UTC, and in ns since the Unix epoch)."""
    from datetime import datetime, timezone

    if origin_ns == 0:
        return "header stamps = data time (time_origin_unix_ns 0)"
    utc = datetime.fromtimestamp(origin_ns // 1_000_000_000, timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
    return (f"header stamps = {utc}.{origin_ns % 1_000_000_000:09d} UTC + camera time "
            f"(time_origin_unix_ns {origin_ns})")


#: stream (StreamStatus.stream) -> (topic, key of one item, only final=True messages count)
STREAM_TOPICS: dict[str, tuple[str, str | None, bool]] = {
    "frames": ("vibro/frames", None, False),
    "dic": ("vibro/dic", "frame_index", False),
    "accel": ("vibro/accel", "block_index", False),
    "accel_impacts": ("vibro/accel_impacts", "index", False),
    "flights": ("vibro/flights", "index", True),
    "impacts": ("vibro/impacts", "index", True),
    "simulation": ("vibro/simulation", "model", False),
    "discrepancy": ("vibro/discrepancy", "index", False),
    "impacts_final_model": ("vibro/impacts_final_model", "index", True),
}


def check_recorded_counts(bag: Path, s: GraphSummary) -> list[str]:
    """Compare each topic's items in the bag (distinct items: a restarted node may repeat some) with what its
    publisher announced in its last StreamStatus (items_sent); one line per topic with items missing."""
    from vibro_ros.bags import deserialize, make_typestore, read_messages

    wanted = {STREAM_TOPICS[k][0]: k for k in s.counts if k in STREAM_TOPICS}
    if not wanted:
        return []
    keys: dict[str, set] = {t: set() for t in wanted}
    unreadable = ""
    try:
        store = make_typestore()
        for i, m in enumerate(read_messages(bag, set(wanted))):
            _, key, final_only = STREAM_TOPICS[wanted[m.topic]]
            if key is None:
                keys[m.topic].add(i)
                continue
            msg = deserialize(m, store)
            if not final_only or msg.final:
                keys[m.topic].add(getattr(msg, key))
    except RecordingError as exc:
        unreadable = f" (bag unreadable: {exc})"
    problems = []
    for topic, stream in sorted(wanted.items()):
        announced = s.counts[stream][0]
        got = len(keys[topic])
        s.recorded[topic] = (announced, got)
        if got < announced:
            publisher = " or ".join(n for n in s.nodes if topic in ALL_SPECS[n].publishes)
            problems.append(f"{topic}: {announced - got} of {announced} messages announced by "
                            f"{publisher or 'its publisher'} missing from the bag{unreadable}")
    return problems


def prepare_environment(domain_id: int | None) -> dict[str, str]:
    env = dict(os.environ)
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
        os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    return env


def bag_outputs(name: str) -> tuple[str, ...]:
    """What a graph run writes for the bag ``name`` (patterns relative to its folder): the bag, its logs."""
    return (f"{name}/metadata.yaml", f"{name}/metadata.yaml.tmp", f"{name}/*.mcap", f"{name}.logs/*.log")


def new_bag_path(bag: str | Path, overwrite: bool = False) -> Path:
    """A bag path free for the recorder, and its log folder ``<bag>.logs`` (refused if either exists,
    unless ``overwrite`` and they look like a graph run's: then removed); the parent is created and
    must be writable."""
    bag = Path(bag)
    prepare_output_entries(bag.parent, (bag.name, f"{bag.name}.logs"), overwrite=overwrite,
                           owned=bag_outputs(bag.name), command="graph")
    return bag


def _importable(module: str) -> bool:
    import importlib.util

    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False
