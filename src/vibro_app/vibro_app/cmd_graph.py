"""``vibro graph <recording> --bag bags/NAME``: run the node graph on a recording, record it, summarise.

The graph runs as separate processes over DDS (:mod:`vibro_bringup.graph_runner`); the summary says
what came through: frames in / tracked / lost, COR per plate, D per model, findings, and whether
the bag holds every item its publishers announced.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from vibro_app.findings_text import finding_line
from vibro_bringup.graph_runner import GraphRun, GraphSummary, execute_graph, new_bag_path, prepare_environment
from vibro_bringup.graph_spec import RunSetup, graph_nodes, write_reference_frame
from vibro_bringup.isolation import namespace_argument
from vibro_fit.coverage import frame_coverage
from vibro_foxglove.view import DEFAULT_PORT
from vibro_io.recording import open_recording
from vibro_model.errors import RecordingError


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
    p.add_argument("--foxglove", action="store_true",
                   help="also serve the graph's topics to a Foxglove app (WebSocket; frames, tracks, COR, "
                        "diagnostics); the summary prints the ws:// URL")
    p.add_argument("--foxglove-port", type=_port, default=None, metavar="N",
                   help=f"TCP port of the Foxglove server (default {DEFAULT_PORT}; implies --foxglove)")
    p.add_argument("--foxglove-host", default=None, metavar="ADDR",
                   help="address the Foxglove server listens on (default 0.0.0.0: every interface, so a lab PC "
                        "without ROS can connect; 127.0.0.1: this PC only; implies --foxglove)")



def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer 1-65535, got {text!r}") from None
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be 1-65535, got {value}")
    return value


def foxglove_parameters(args: argparse.Namespace) -> dict | None:
    """The Foxglove bridge's parameters from ``--foxglove``/``--foxglove-port``/``--foxglove-host`` (None: no
    bridge); RecordingError when the port cannot be bound on that address (in use, or not this machine's)."""
    if not (args.foxglove or args.foxglove_port is not None or args.foxglove_host is not None):
        return None
    host = args.foxglove_host or "0.0.0.0"
    port = args.foxglove_port or DEFAULT_PORT
    import socket

    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind((host, port))
    except OSError as exc:
        raise RecordingError(f"--foxglove-port {port} --foxglove-host {host}: cannot serve there "
                             f"({exc.strerror or exc}); choose another port") from None
    return {"host": host, "port": port}


def _print_cor_table(s: GraphSummary) -> None:
    print(f"{'plate':8s} {'n':>4s} {'COR mean':>9s} {'COR std':>8s}")
    for plate in ("bottom", "top"):
        cors = [m.cor for m in (s.final_impacts or s.impacts).values() if m.plate == plate and math.isfinite(m.cor)]
        if cors:
            mean = sum(cors) / len(cors)
            std = math.sqrt(sum((c - mean) ** 2 for c in cors) / max(1, len(cors) - 1))
            print(f"{plate:8s} {len(cors):4d} {mean:9.4f} {std:8.4f}")
        else:
            print(f"{plate:8s} {0:4d} {'-':>9s} {'-':>8s}")


def print_summary(s: GraphSummary, bag: Path) -> None:
    """Print what the monitor saw of a run (frames, CORs, deviations, findings, problems) and its ``bag``."""
    if s.identity:
        print(s.identity)
    announced = _print_frame_counts(s)
    _print_accel_coverage(s, announced)
    _print_results(s)
    _print_problems(s)
    if s.foxglove_url:
        print(f"foxglove: {s.foxglove_url} (served while the graph ran)")
    print(f"bag: {bag}")


def _print_frame_counts(s: GraphSummary) -> int:
    """Print frames in / tracked / lost, the reasons and the restarts; returns the frames announced."""
    # the tracker's own end-of-stream count is authoritative (one DicFrame per frame slot);
    # the monitor's view of vibro/dic only adds the reasons. A restarted tracker only counts what it
    # answered itself, so after a restart the union of the frame indices seen on vibro/dic counts.
    restarted = s.restarts.get("dic_tracker", 0)
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
    return announced


def _print_accel_coverage(s: GraphSummary, announced: int) -> None:
    """Print the accelerometers' coverage note of the ``announced`` frames, if it has one."""
    if s.accel_span_s and s.camera is not None and announced > 0:
        cam = s.camera
        cov = frame_coverage([cam.frame_time_s(0), cam.frame_time_s(announced - 1)], s.accel_span_s,
                             sorted(s.accel_impacts_s.values()), None, 1.0 / cam.fps)
        if cov.message():
            print(f"note: {cov.message()}")


def _print_results(s: GraphSummary) -> None:
    """Print the COR table (or why it is withheld), the deviation D per model and the findings."""
    withheld = s.counts.get("impacts", (0, 0))[1] if s.finished.get("impacts") and not s.final_impacts else 0
    if withheld:  # the fitter refused the run (its cross-checks): its streamed previews are not results
        print(f"COR table withheld: trajectory_fitter published no final impact ({withheld} withheld; its refusal "
              "is in the FAILED lines below)")
    else:
        _print_cor_table(s)
    for model, d in sorted(s.deviations.items()):
        print(f"D {model:12s} {100 * d:6.2f} %")
    if not s.findings:   # no impact: nothing was analysed, which is not "no finding"
        print("findings: none published" + ("" if s.final_impacts or s.impacts else
                                            " (no impact identified: the discrepancy analysis had nothing to compare)"))
    for f in s.findings:
        sigmas = dict(zip(f.parameter_names, f.parameter_std))
        print(finding_line(f.effect, dict(zip(f.parameter_names, f.parameter_values)), sigmas,
                           f.deviation_before, f.deviation_after) + f"; {f.where}")


def _print_problems(s: GraphSummary) -> None:
    """Print what the bag recorded per topic, the topics with messages missing and the nodes that failed."""
    if s.recorded:
        print("recorded: " + ", ".join(f"{t} {got}/{n}" for t, (n, got) in sorted(s.recorded.items())))
    for problem in s.count_problems:
        print(f"MISSING: {problem}")
    for failure in s.failures:
        print(f"FAILED: {failure.describe()}")


def run(args: argparse.Namespace) -> int:
    recording = open_recording(args.recording)  # validate before starting anything
    foxglove = foxglove_parameters(args)
    bag = new_bag_path(args.bag, args.overwrite)
    env = prepare_environment(args.domain_id)
    sources = [s for s in graph_nodes(bag=True, with_accel=recording.has_accel) if s.role == "source"]
    from vibro_ros.node_support import HISTORY_DEPTH

    t0 = time.monotonic()
    graph_run = GraphRun(
        timeout_s=args.timeout_s, env=env, respawn=args.respawn,
        reference=lambda folder: write_reference_frame(recording.path, folder / "reference_frame0.png"),
        namespace=args.namespace, history_depth=max(HISTORY_DEPTH, len(recording.frames) + 1))
    ok, summary, log_dir = execute_graph(recording.path, bag, sources, with_accel=recording.has_accel, run=graph_run,
                                         setup=RunSetup(base=args.params, foxglove=foxglove))
    print(f"graph: {time.monotonic() - t0:.1f} s, logs in {log_dir}")
    print_summary(summary, bag)
    return incomplete_exit(bag, "vibro graph") if ok else failed_exit(summary)


def failed_exit(summary: GraphSummary) -> int:
    """The exit code of a run a node ended: 2 when every node that failed refused its input (exit code 2: bad
    input, a refused track or identification), as ``vibro analyze`` and ``vibro results`` of the bag exit on the
    same input; else 1 (a node crashed, was killed, or the run timed out)."""
    codes = {f.code for f in summary.failures}
    return 2 if codes == {2} else 1


def incomplete_exit(bag: Path, command: str) -> int:
    """0 when the recorded run is complete, else 1 with the reason on stderr: the exit code ``vibro results`` gives
    the same bag (:func:`vibro_app.bag_results.document_from_bag`), so every path ends a run that lost data
    alike (a tracker killed and restarted mid-run leaves frames without DIC: the run's results are incomplete)."""
    from vibro_app.bag_results import document_from_bag

    doc = document_from_bag(bag)
    if doc.complete:
        return 0
    print(f"{command}: error: the run is incomplete ({doc.warnings[0]}); `vibro results {bag}` writes its results "
          "marked \"complete\": false", file=sys.stderr)
    return 1
