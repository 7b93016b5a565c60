"""``vibro graph <recording> --bag bags/NAME``: run the node graph on a recording, record it, summarise.

Every node runs in its own OS process and talks over DDS. This command starts them
(sinks and processing first, sources last), watches ``vibro/status`` until the last
stage has finished, stops everything with SIGINT, and prints what came through: frames
in / tracked / lost (a lost frame is never silent), COR per plate, D per model, findings.
Each run lives in its own namespace with its own run id (see isolation.py), so two runs on
one domain never mix; a node that sees foreign input stops, and the run fails with its error.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from vibro_io.errors import RecordingError
from vibro_io.recording import open_recording

from .graph_spec import BAG_SOURCE, NODES, NodeSpec, node_parameters, write_params_file, write_reference_frame
from .isolation import RunIdentity, namespace_argument, new_run_identity


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("graph", help="run the ROS node graph on a recording and record it to a bag")
    p.add_argument("recording", help="recording directory")
    p.add_argument("--bag", required=True, help="bag directory to create, e.g. bags/run1")
    add_run_options(p)
    p.set_defaults(func=run)


def _non_negative_int(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _positive_float(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


MAX_DOMAIN_ID = 232  # Fast DDS on Linux, default port mapping: higher ids give ports above 65535


def _domain_id(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer 0-{MAX_DOMAIN_ID}, got {text!r}") from None
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise argparse.ArgumentTypeError(f"must be 0-{MAX_DOMAIN_ID}, got {value}")
    return value


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Options every command that runs the node graph takes (vibro graph, vibro replay)."""
    p.add_argument("--params", help="parameters YAML (default: vibro_bringup/config/vibro.yaml)")
    p.add_argument("--timeout-s", type=_positive_float, default=900.0, help="give up after this many seconds")
    p.add_argument("--domain-id", type=_domain_id, metavar="ID",
                   help=f"ROS_DOMAIN_ID for this run, 0-{MAX_DOMAIN_ID} (the ROS 2 range for Fast DDS on Linux "
                        "with default ports; default: inherited)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the bag and logs (and, for replay, the outputs) of an earlier run of this command")
    p.add_argument("--namespace", type=namespace_argument, metavar="NS",
                   help="ROS namespace of this run's nodes and topics (default: /vibro_<run id>, new per run, so "
                        "runs on one domain stay apart; / = none)")
    p.add_argument("--respawn", type=_non_negative_int, default=2, metavar="N",
                   help="restart a processing node that dies mid-run at most N times (default 2; 0 = never)")


@dataclass
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
    identity: str = ""  # run id, namespace and domain of the run


class GraphRun:
    """Processes of one graph run plus an in-process monitor node."""

    def __init__(self, recording: Path, bag: Path, params_file: Path, env: dict[str, str], respawn: int = 2,
                 identity: RunIdentity | None = None):
        self.recording = recording
        self.identity = identity or RunIdentity("", "/")
        self.respawn = max(0, int(respawn))
        self.specs: dict[str, NodeSpec] = {}
        self.bag = bag
        self.params_file = params_file
        self.env = env
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.summary = GraphSummary()

    def start(self, spec: NodeSpec, log_dir: Path, append: bool = False) -> None:
        log = log_dir / f"{spec.name}.log"
        self.logs[spec.name] = log
        self.specs[spec.name] = spec
        with log.open("a" if append else "w") as out:  # the child keeps its own descriptor
            self.procs[spec.name] = subprocess.Popen(
                [sys.executable, "-m", "vibro_bringup.child", spec.module, "--ros-args", "--params-file",
                 str(self.params_file), "-r", f"__node:={spec.name}", "-r", f"__ns:={self.identity.namespace}"],
                stdout=out, stderr=subprocess.STDOUT, env=self.env)

    def supervise(self) -> list[str]:
        """Restart processing nodes that died mid-run (like a launch file's ``respawn=True``, at most
        ``respawn`` times each, same params file, log appended); return the dead nodes not restarted."""
        given_up = []
        for name in self.died():
            spec = self.specs.get(name)
            done = self.summary.restarts.get(name, 0)
            code = self.procs[name].returncode
            # exit code 2: the node refused its input or parameters (e.g. another run's data): a restart would too
            if spec is None or spec.role != "processing" or done >= self.respawn or code == 2:
                given_up.append(name)
                continue
            self.summary.restarts[name] = done + 1
            log = self.logs[name]
            with log.open("a") as out:
                out.write(f"\n--- vibro graph: {name} exited with {code}; restarted "
                          f"({done + 1}/{self.respawn}) ---\n")
            self.start(spec, log.parent, append=True)
            print(f"{name} exited with {code}; restarted ({done + 1}/{self.respawn})", file=sys.stderr, flush=True)
        return given_up

    def error_of(self, name: str) -> str:
        """The last error line a node logged (its log file), '' when none."""
        log = self.logs.get(name)
        try:
            lines = log.read_text(errors="replace").splitlines() if log is not None else []
        except OSError:
            return ""
        for line in reversed(lines):
            if "[ERROR]" in line:
                return line.split("]: ", 1)[-1].strip()
        return ""

    def describe_dead(self, names: list[str]) -> str:
        """'node exited with CODE: its error' for each of ``names``, and where the first one's log is."""
        parts = []
        for name in names:
            error = self.error_of(name)
            parts.append(f"{name} exited with {self.procs[name].returncode}" + (f": {error}" if error else ""))
        return "; ".join(parts) + (f" (see {self.logs[names[0]]})" if names else "")

    def died(self) -> list[str]:
        """Non-source nodes that exited on their own (a source exits when done)."""
        roles = {s.name: s.role for s in NODES}
        return [n for n, p in self.procs.items() if p.poll() is not None and roles.get(n, "source") != "source"]

    def stop(self, grace_s: float = 20.0, drain_s: float = 1.0) -> list[str]:
        """SIGINT every node still running, sources first; the recorder only once the others have exited
        and ``drain_s`` has passed, so it takes their last messages (final results) before closing the bag.
        SIGKILL what has not exited after ``grace_s``. Returns the names of nodes that had to be killed."""
        roles = {s.name: s.role for s in NODES}
        others = [n for n in self.procs if roles.get(n, "source") == "source"] + \
                 [s.name for s in NODES if s.role == "processing"]
        deadline = time.monotonic() + grace_s
        killed = self._interrupt(others, deadline)
        if self.procs.get("recorder") is not None and self.procs["recorder"].poll() is None:
            time.sleep(drain_s)
        killed += self._interrupt(["recorder"], deadline)
        if killed:
            print(f"vibro graph: {', '.join(killed)} did not stop within {grace_s:g} s of SIGINT and was killed",
                  file=sys.stderr)
        return killed

    def _interrupt(self, names: list[str], deadline: float) -> list[str]:
        """SIGINT ``names`` (those still running), wait for them until ``deadline``, SIGKILL the rest."""
        for name in names:
            proc = self.procs.get(name)
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        killed = []
        for name in names:
            proc = self.procs.get(name)
            if proc is None:
                continue
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                killed.append(name)
        return killed


class Monitor:
    """An in-process node that checks the graph is wired before data flows, then watches it."""

    def __init__(self, run: GraphRun):
        import rclpy

        from vibro_ros import topics
        from vibro_ros.node_support import RESULTS_QOS, STREAM_QOS, make_executor
        from vibro_msgs.msg import (AccelBlock, AccelImpact, DicFrame, DiscrepancyFinding, ImpactEstimate,
                                    SimulationResult, StreamStatus)

        self.run = run
        s = self.summary = run.summary
        run_id = run.identity.run_id
        rclpy.init()
        self.node = node = rclpy.create_node("vibro_graph_monitor", namespace=run.identity.namespace)
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
            from vibro_io.rig import load_rig
            s.camera = load_rig(Path(run.recording) / "rig.yaml").camera
        except (RecordingError, OSError):
            s.camera = None

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def wait_wired(self, expected: dict[str, tuple[set[str], set[str]]], timeout_s: float) -> bool:
        """Wait until, for each topic, the named nodes are seen publishing and subscribing to it (topics and
        nodes in this run's namespace)."""
        deadline = time.monotonic() + timeout_s
        node = self.node
        ns = self.run.identity.namespace.rstrip("/")

        def names(infos) -> set[str]:
            return {i.node_name for i in infos if i.node_namespace.rstrip("/") == ns}

        while time.monotonic() < deadline:
            self.spin(0.1)
            if all(pubs <= names(node.get_publishers_info_by_topic(t))
                   and subs <= names(node.get_subscriptions_info_by_topic(t))
                   for t, (pubs, subs) in expected.items()):
                self.spin(0.5)  # let the nodes' own discovery settle too
                return True
            if self.run.died():
                return False
        return False

    def watch(self, until_streams: tuple[str, ...], timeout_s: float) -> bool:
        """Spin until every stream in ``until_streams`` is finished; False on timeout or a dead node."""
        s = self.summary
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.spin(0.05)
            if s.finished.get("dic"):  # the tracker only finishes after the frame source did
                s.finished["frames"] = True
            if all(s.finished.get(k) for k in until_streams):
                self.spin(1.0)  # collect stragglers
                return True
            dead = self.run.supervise()
            if dead:
                print(f"vibro graph: node(s) {', '.join(dead)} exited early"
                      f"{' (restarts used up)' if any(self.run.summary.restarts.get(n) for n in dead) else ''}: "
                      f"{self.run.describe_dead(dead)}",
                      file=sys.stderr)
                return False
        return False

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


def expected_wiring(names: set[str]) -> dict[str, tuple[set[str], set[str]]]:
    """(publisher nodes, subscriber nodes) each topic must show before the sources start."""
    from vibro_ros import topics

    def only(*nodes: str) -> set[str]:
        return {x for x in nodes if x in names}

    return {
        topics.FRAMES.name: (set(), only("dic_tracker", "recorder")),
        topics.DIC.name: (only("dic_tracker"), only("trajectory_fitter", "simulator", "discrepancy", "recorder")),
        topics.ACCEL.name: (set(), only("impact_detector", "trajectory_fitter", "recorder")),
        topics.IMPACTS.name: (only("trajectory_fitter"), only("simulator", "discrepancy", "recorder")),
        topics.STATUS.name: (set(), only("dic_tracker", "trajectory_fitter", "simulator", "discrepancy",
                                         "impact_detector")),
    }


def print_summary(s: GraphSummary, bag: Path) -> None:
    # the tracker's own end-of-stream count is authoritative (one DicFrame per frame slot);
    # the monitor's view of vibro/dic only adds the reasons. A restarted tracker only counts what it
    # answered itself, so after a restart the union of the frame indices seen on vibro/dic counts.
    restarted = s.restarts.get("dic_tracker", 0)
    if s.identity:
        print(s.identity)
    published, lost = (s.dic_frames, s.dic_lost) if restarted else s.counts.get("dic", (s.dic_frames, s.dic_lost))
    tracked = published - lost
    announced = s.frames_announced
    note = f" (unreadable at the source: {s.frames_unreadable})" if s.frames_unreadable else ""
    if announced == 0 and published:
        # the source's own count did not reach this monitor; the tracker answers every frame slot
        announced = published
        note += " (frame count from the tracker: the source's status was not received)"
    never = max(0, announced - published)
    print(f"frames in {announced} / tracked {tracked} / lost {lost + never}{note}")
    for reason, n in sorted(s.lost_reasons.items(), key=lambda kv: -kv[1]):
        print(f"  lost x{n}: {reason}")
    if never:
        why = (f" (dic_tracker restarted {restarted}x mid-run: frames sent while it was down)"
               if restarted else "")
        print(f"  lost x{never}: no DIC result ever published{why}")
    for node, n in sorted(s.restarts.items()):
        print(f"restarted: {node} x{n}")
    if s.accel_span_s and s.camera is not None and announced > 0:
        from vibro_fit.coverage import frame_coverage

        cam = s.camera
        cov = frame_coverage([cam.frame_time_s(0), cam.frame_time_s(announced - 1)], s.accel_span_s,
                             sorted(s.accel_impacts_s.values()), None, 1.0 / cam.fps)
        if cov.message():
            print(f"note: {cov.message()}")
    print(f"{'plate':8s} {'n':>4s} {'COR mean':>9s} {'COR std':>8s}")
    for plate in ("bottom", "top"):
        cors = [m.cor for m in (s.final_impacts or s.impacts).values() if m.plate == plate and math.isfinite(m.cor)]
        if cors:
            mean = sum(cors) / len(cors)
            std = math.sqrt(sum((c - mean) ** 2 for c in cors) / max(1, len(cors) - 1))
            print(f"{plate:8s} {len(cors):4d} {mean:9.4f} {std:8.4f}")
        else:
            print(f"{plate:8s} {0:4d} {'-':>9s} {'-':>8s}")
    for model, d in sorted(s.deviations.items()):
        print(f"D {model:12s} {100 * d:6.2f} %")
    if s.findings:
        for f in s.findings:
            params = ", ".join(f"{n}={v:.4g}" for n, v in zip(f.parameter_names, f.parameter_values))
            print(f"finding: {f.effect} ({params}) D {100 * f.deviation_before:.2f} % -> "
                  f"{100 * f.deviation_after:.2f} %; {f.where}")
    else:
        print("findings: none published")
    print(f"bag: {bag}")


def execute_graph(rig_dir: Path, bag: Path, sources: list[NodeSpec], *, with_accel: bool, params_base: str | None,
                  timeout_s: float, env: dict[str, str], extra_params: dict | None = None, respawn: int = 2,
                  reference: Callable[[Path], Path | None] | None = None, namespace: str | None = None,
                  history_depth: int | None = None) -> tuple[bool, GraphSummary, Path]:
    """Start the processing nodes, check the wiring, start ``sources``, watch until done, stop all.

    ``rig_dir`` holds the rig.yaml (and, for the file sources, the recording). Returns
    (finished, summary, log folder). ``reference(folder)`` writes frame 0 as an image file into the
    run's temporary folder for dic_tracker's ``reference_image``; ``respawn``: restarts allowed per node.
    The run gets a new run id and lives in ``namespace`` (default ``/vibro_<run id>``); ``history_depth``:
    items the latched histories of vibro/dic and vibro/accel keep (default: the nodes' own).
    """
    identity = new_run_identity(namespace)
    processing = [s for s in NODES if s.role != "source" and _importable(s.module)]
    missing = [s.name for s in NODES if s.role != "source" and s not in processing]
    if missing:
        print(f"vibro graph: nodes not available in this checkout: {', '.join(missing)}", file=sys.stderr)
    if not with_accel:
        processing = [s for s in processing if s.name != "impact_detector"]
    names = {s.name for s in processing} | {s.name for s in sources}
    until = ("frames",) + tuple(k for k, node in (("dic", "dic_tracker"), ("impacts", "trajectory_fitter"),
                                                  ("simulation", "simulator"), ("discrepancy", "discrepancy"))
                                if node in names)
    wiring_names = names
    with tempfile.TemporaryDirectory(prefix="vibro-graph-") as tmp:
        ref_png = reference(Path(tmp)) if reference is not None else None
        params = node_parameters(rig_dir, bag, params_base, with_accel, reference_image=ref_png)
        # the tracker holds its results until every vibro/dic reader (this monitor too) has matched, so that
        # a tracker restarted mid-run loses frames only visibly, never for one reader alone
        dic_readers = {"trajectory_fitter", "simulator", "discrepancy", "recorder", "frame_source", "bag_source"}
        params.setdefault("dic_tracker", {})["wait_for_subscribers"] = 1 + len(names & dic_readers)
        for spec in (*NODES, BAG_SOURCE):  # one run: its id, and histories a restarted node can recover from
            params.setdefault(spec.name, {})["run_id"] = identity.run_id
            if history_depth is not None:
                params[spec.name]["history_depth"] = int(history_depth)
        for source in ("accel_source", "bag_source"):
            params[source]["keep_history"] = True
        for node, values in (extra_params or {}).items():
            params.setdefault(node, {}).update(values)
        params_file = write_params_file(params, Path(tmp) / "params.yaml")
        log_dir = bag.parent / f"{bag.name}.logs"
        log_dir.mkdir(exist_ok=True)
        graph = GraphRun(rig_dir, bag, params_file, env, respawn, identity)
        graph.summary.identity = identity.describe(env)
        print(graph.summary.identity, flush=True)
        monitor = None
        ok = False
        try:
            monitor = Monitor(graph)
            for spec in processing:
                graph.start(spec, log_dir)
            if not monitor.wait_wired(expected_wiring(wiring_names), 120.0):
                dead = graph.died()
                raise RecordingError("the graph did not come up: " + (
                    graph.describe_dead(dead) if dead else "topics not matched within 120 s"))
            for spec in sources:
                graph.start(spec, log_dir)
            ok = monitor.watch(until, timeout_s)
        finally:
            graph.stop()
            if monitor is not None:
                monitor.close()
    if not ok:
        waiting = [k for k in until if not graph.summary.finished.get(k)]
        print("vibro graph: the graph did not finish (timeout or a node died); streams not finished: "
              f"{', '.join(waiting) or 'none'}; the bag holds what was recorded", file=sys.stderr)
    return ok, graph.summary, log_dir


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
    from vibro_io.outputs import prepare_output_entries

    bag = Path(bag)
    prepare_output_entries(bag.parent, (bag.name, f"{bag.name}.logs"), overwrite=overwrite,
                           owned=bag_outputs(bag.name), command="graph")
    return bag


def run(args: argparse.Namespace) -> int:
    recording = open_recording(args.recording)  # validate before starting anything
    bag = new_bag_path(args.bag, args.overwrite)
    env = prepare_environment(args.domain_id)
    sources = [s for s in NODES if s.role == "source" and (recording.has_accel or s.name != "accel_source")]
    from vibro_ros.node_support import HISTORY_DEPTH

    t0 = time.monotonic()
    ok, summary, log_dir = execute_graph(
        recording.path, bag, sources, with_accel=recording.has_accel, params_base=args.params,
        timeout_s=args.timeout_s, env=env, respawn=args.respawn,
        reference=lambda folder: write_reference_frame(recording.path, folder / "reference_frame0.png"),
        namespace=args.namespace, history_depth=max(HISTORY_DEPTH, len(recording.frames) + 1))
    print(f"graph: {time.monotonic() - t0:.1f} s, logs in {log_dir}")
    print_summary(summary, bag)
    return 0 if ok else 1


def _importable(module: str) -> bool:
    import importlib.util

    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False
