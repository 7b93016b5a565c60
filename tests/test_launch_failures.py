"""Under ros2 launch, failures end the run loudly (issue #25): the launch file's arguments and exit handlers.

The launch file's own functions run here with a stand-in for the launch API (tests/launch_api_double.py; the real
launch is not installable here): its arguments (bag:=none, record, namespace, reference_image,
time_origin_unix_ns) and the exit handler of every node, fired with the exit codes launch reports (negative:
killed by a signal). The verdicts come from vibro_bringup.exit_policy, the rule vibro graph's supervisor follows.
Nodes stopped by Ctrl-C while they still import numpy/scipy/rclpy are real processes, started by the console
scripts' entry points as ros2 launch starts them.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import launch_api_double as L  # noqa: E402

from vibro_bringup import launch_arguments as A  # noqa: E402
from vibro_bringup.exit_policy import END_RUN, FINISHED, RESTART, exit_verdict  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def launch_file():
    return L.load_launch_file()


# ---------------------------------------------------------------- 1. no bag, said the way ros2launch accepts
@pytest.mark.parametrize("text", ["none", "None", "NONE", "false", "off", "", '""', "''"])
def test_bag_words_for_no_recorder(text: str) -> None:
    assert A.bag_directory(text) is None


def test_bag_path_and_record_flag(tmp_path: Path) -> None:
    assert A.bag_directory(str(tmp_path / "run1")) == str(tmp_path / "run1")
    assert A.bag_directory(str(tmp_path / "run1"), record="false") is None
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "metadata.yaml").write_text("x")
    with pytest.raises(A.LaunchArgumentError, match=r"^bag:=.*old: exists and is not an empty folder"):
        A.bag_directory(str(tmp_path / "old"))
    with pytest.raises(A.LaunchArgumentError, match=r"^record:=maybe: expected true or false"):
        A.bag_directory(str(tmp_path / "run2"), record="maybe")


def test_no_document_writes_a_launch_argument_ros2launch_refuses() -> None:
    """ros2launch refuses `name:=` with nothing after it ("malformed launch argument"), which is what a shell
    makes of bag:="": no README, doc page or launch file docstring may show one."""
    empty = re.compile(r"\b\w+:=(?:\"\"|''|(?=\s|$|`))")
    texts = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")), L.LAUNCH_FILE]
    found = [(p.name, m.group(0)) for p in texts for m in empty.finditer(p.read_text())]
    assert not found, found


def test_recorder_only_with_a_bag(launch_file, tiny_recording: Path, tmp_path: Path) -> None:
    def names(**given):
        return set(L.nodes_and_handlers(L.run_opaque(launch_file, recording=str(tiny_recording), **given)))

    assert "recorder" not in names()  # the default: bag:=none
    assert "recorder" not in names(bag="none")
    assert "recorder" in names(bag=str(tmp_path / "bag"))
    assert "recorder" not in names(bag=str(tmp_path / "bag"), record="false")


# ---------------------------------------------------------------- 2. exits: restart crashes, end the run otherwise
class RunEndedCheck:
    """Fire exits into the launch file's handlers the way launch does."""

    def __init__(self, launch_file, recording: Path, **given: str):
        self.module = launch_file
        self.nodes = L.nodes_and_handlers(L.run_opaque(launch_file, recording=str(recording), **given))

    def fire(self, name: str, code: int, handler=None, shutdown: bool = False):
        handler = handler or self.nodes[name][1]
        return handler.on_exit(L.ProcessExited(code), L.Context({}, is_shutdown=shutdown))

    def ends_run(self, name: str, code: int, handler=None) -> str:
        with pytest.raises(self.module.RunEnded) as exc:
            self.fire(name, code, handler)
        return str(exc.value)


def test_a_dead_source_or_recorder_ends_the_launch_naming_it(launch_file, tiny_recording, tmp_path) -> None:
    run = RunEndedCheck(launch_file, tiny_recording, bag=str(tmp_path / "bag"))
    assert {"frame_source", "accel_source", "recorder"} <= set(run.nodes)
    line = run.ends_run("frame_source", -signal.SIGKILL)
    assert line.startswith("vibro: frame_source killed by SIGKILL: no more input can come"), line
    assert "accel_source exit code 1" in run.ends_run("accel_source", 1)
    assert run.ends_run("recorder", -signal.SIGSEGV).startswith("vibro: recorder killed by SIGSEGV: nothing more is "
                                                                "recorded")
    for name in run.nodes:  # a node that finished its stream, and anything stopping while launch shuts down
        assert run.fire(name, 0) is None
        assert run.fire(name, -signal.SIGKILL, shutdown=True) is None


def test_a_refusal_is_never_restarted(launch_file, tiny_recording, tmp_path) -> None:
    """Exit code 2 (the guard: another run's data; bad parameters) ends the run from every node, live too."""
    for live in ("false", "true"):
        run = RunEndedCheck(launch_file, tiny_recording, bag=str(tmp_path / f"bag{live}"), live=live)
        for name in run.nodes:
            assert f"vibro: {name} refused its input or parameters (exit code 2" in run.ends_run(name, 2)


def test_a_crashed_processing_node_restarts_until_respawn_max(launch_file, tiny_recording) -> None:
    run = RunEndedCheck(launch_file, tiny_recording, respawn_max="2", respawn_delay="0.5")
    handler = run.nodes["dic_tracker"][1]
    for attempt in (1, 2):
        log, timer = run.fire("dic_tracker", -signal.SIGKILL, handler)
        assert isinstance(log, L.LogInfo) and f"restarting it ({attempt}/2) in 0.5 s" in log.msg, log
        assert isinstance(timer, L.TimerAction) and timer.period == 0.5
        (again, handler), = L.nodes_and_handlers(timer.actions).values()
        assert again.name == "dic_tracker" and again.parameters == run.nodes["dic_tracker"][0].parameters
    line = run.ends_run("dic_tracker", 1, handler)
    assert "dic_tracker exit code 1 after 2 restart(s)" in line, line


def test_live_processing_nodes_restart_whatever_their_exit(launch_file, tiny_recording) -> None:
    run = RunEndedCheck(launch_file, tiny_recording, live="true", camera_topic="/camera/image_raw")
    handler = run.nodes["dic_tracker"][1]
    for _ in range(5):  # no limit live; a live node that exits 0 by itself is restarted too
        log, timer = run.fire("dic_tracker", 0, handler)
        (_, handler), = L.nodes_and_handlers(timer.actions).values()
    assert "frame_source" not in run.nodes


def test_exit_policy_is_vibro_graphs() -> None:
    """The same verdicts the supervisor of vibro graph acts on (tests/test_supervisor.py runs it)."""
    v = lambda *a, **k: exit_verdict(*a, restarts_done=k.get("done", 0), respawn_max=2,  # noqa: E731
                                     live=k.get("live", False)).action
    assert v("dic_tracker", "processing", 0) == FINISHED
    assert v("dic_tracker", "processing", -9) == RESTART
    assert v("dic_tracker", "processing", -9, done=2) == END_RUN
    assert v("dic_tracker", "processing", 2) == END_RUN
    assert v("frame_source", "source", 1) == END_RUN
    assert v("frame_source", "source", 0) == FINISHED
    assert v("recorder", "sink", -15) == END_RUN
    assert v("foxglove_bridge", "viewer", 1) == RESTART
    assert v("dic_tracker", "processing", 0, live=True) == RESTART
    assert v("dic_tracker", "processing", -9, done=50, live=True) == RESTART


# ---------------------------------------------------------------- 4. namespace; 5. live reference and clock
def test_namespace_argument_puts_every_node_there(launch_file, tiny_recording, tmp_path) -> None:
    run = RunEndedCheck(launch_file, tiny_recording, bag=str(tmp_path / "bag"), namespace="lab1")
    assert {n.namespace for n, _ in run.nodes.values()} == {"/lab1"}
    assert {n.namespace for n, _ in RunEndedCheck(launch_file, tiny_recording).nodes.values()} == {None}
    with pytest.raises(A.LaunchArgumentError, match=r"^namespace:=1lab: .* is not a ROS namespace"):
        L.run_opaque(launch_file, recording=str(tiny_recording), namespace="1lab")


def test_live_reference_image_and_time_origin(launch_file, tiny_recording, tmp_path) -> None:
    from vibro_bringup.graph_spec import write_reference_frame

    png = write_reference_frame(tiny_recording, tmp_path / "frame0.png")
    origin = 1_764_000_000_123_456_789
    run = RunEndedCheck(launch_file, tiny_recording, live="true", camera_topic="/camera/image_raw",
                        reference_image=str(png), time_origin_unix_ns=str(origin))
    tracker = run.nodes["dic_tracker"][0].parameters[0]
    assert tracker["reference_image"] == str(png.resolve()) and tracker["live_camera"] is True
    assert {n.parameters[0]["time_origin_unix_ns"] for n, _ in run.nodes.values()} == {origin}
    for bad, why in (("1764000000", "not a wall time in nanoseconds"), ("soon", "expected an integer")):
        with pytest.raises(A.LaunchArgumentError, match=f"^time_origin_unix_ns:={bad}: {why}"):
            L.run_opaque(launch_file, recording=str(tiny_recording), live="true", time_origin_unix_ns=bad)
    for name in ("reference_image", "params_file"):
        with pytest.raises(A.LaunchArgumentError, match=f"^{name}:=.*nowhere.png: no such file"):
            L.run_opaque(launch_file, recording=str(tiny_recording), **{name: str(tmp_path / "nowhere.png")})
    (tmp_path / "not.png").write_text("text")
    with pytest.raises(A.LaunchArgumentError, match=r"^reference_image:=.*not.png: not an image"):
        L.run_opaque(launch_file, recording=str(tiny_recording), reference_image=str(tmp_path / "not.png"))


# ---------------------------------------------------------------- 6. Ctrl-C while a node still imports
def _mapped(pid: int, name: str) -> bool:
    try:
        return name in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


@pytest.mark.parametrize("executable", ["dic_tracker", "simulator", "trajectory_fitter"])
def test_ctrl_c_while_a_node_imports_is_a_clean_exit(executable: str, tiny_recording: Path) -> None:
    """SIGINT once numpy's extension is loaded (the node module is importing scipy, OpenCV, rclpy): exit 0, one
    line, no KeyboardInterrupt traceback; started as ros2 launch starts it (tests/launch_like.py)."""
    from launch_like import console_scripts

    module, func = console_scripts()[(next(p for (p, e) in console_scripts() if e == executable), executable)] \
        .split(":")
    proc = subprocess.Popen([sys.executable, "-c", f"import sys; from {module} import {func}; sys.exit({func}())",
                             "--ros-args", "-r", f"__node:={executable}"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    deadline = time.monotonic() + 60
    while not _mapped(proc.pid, "_multiarray_umath") and proc.poll() is None:
        assert time.monotonic() < deadline, "numpy never loaded"
        time.sleep(0.002)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0 and "Traceback" not in err, (proc.returncode, err[-2000:])
    assert "stopped by SIGINT while starting" in err or "left the ROS graph" in err, err[-2000:]


def test_a_live_camera_started_before_the_graph_is_told_its_origin() -> None:
    """A driver stamping with its own clock, started 4.246 s before the graph: its first image is frame 4246 on
    the run's clock. The hint gives the origin that makes that image frame 0 (stamp minus t0_s), in integer ns,
    and applying it does give frame 0 (the tracker's k = round((t - t0_s) * fps), t = stamp - origin)."""
    from vibro_ros.lab_clock import data_time_from_stamp_ns, live_origin_hint

    stamp = 1_764_000_004_246_000_123
    fps, t0_s = 1000.0, 0.0125
    hint = live_origin_hint(4246, stamp, t0_s)
    origin = int(re.search(r"time_origin_unix_ns:=(\d+)", hint)[1])
    assert round((data_time_from_stamp_ns(origin, stamp) - t0_s) * fps) == 0
    assert origin == stamp - 12_500_000 and "frame 4246" in hint
    assert A.time_origin_ns(str(origin)) == origin  # the launch argument takes it as printed


def test_an_incomplete_run_ends_the_launch_as_it_ends_vibro_graph(launch_file, tiny_recording, tmp_path) -> None:
    """Exit code 3 (vibro_ros.exit_codes.INCOMPLETE: the discrepancy node found frame slots the graph never
    tracked and judged nothing): never restarted, the run ends with one line saying it is incomplete, under ros2
    launch as under vibro graph (the same verdict)."""
    from vibro_ros.exit_codes import INCOMPLETE

    run = RunEndedCheck(launch_file, tiny_recording, bag=str(tmp_path / "bag"))
    line = run.ends_run("discrepancy", INCOMPLETE)
    assert "discrepancy: the run is incomplete (exit code 3" in line, line
    assert exit_verdict("discrepancy", "processing", INCOMPLETE, restarts_done=0, respawn_max=2).action == END_RUN
