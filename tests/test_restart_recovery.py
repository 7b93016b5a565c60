"""A stateful node restarted mid-run (issue #16.6) recovers its state from the latched histories of
vibro/dic and vibro/accel, or stops with an error naming what it missed: never a run that ends with
exit code 0 and fewer impacts.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from vibro_sim.synth import SynthConfig, synthesize

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_graph_faults import VIBRO, _params, _pids  # noqa: E402


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("restart") / "rec"
    synthesize(out, SynthConfig(frames=300, seed=11), progress=False)
    return out


def test_trajectory_fitter_killed_mid_run_recovers_every_impact(recording: Path, tmp_path: Path,
                                                                ros_domain: str) -> None:
    bag = tmp_path / "bag"
    # 60 frames/s: 5 s of streaming; the fitter is killed 1.5 s in, with about 90 frames fitted
    graph = subprocess.Popen([*VIBRO, "graph", str(recording), "--bag", str(bag), "--params",
                              str(_params(tmp_path, 60.0)), "--domain-id", ros_domain, "--timeout-s", "150"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        source_log = tmp_path / "bag.logs" / "frame_source.log"
        deadline = time.monotonic() + 150
        while "streaming:" not in (source_log.read_text() if source_log.exists() else ""):
            if time.monotonic() > deadline or graph.poll() is not None:
                out, err = graph.communicate()
                pytest.fail(f"frame_source never started streaming (exit {graph.returncode})\n{out}\n{err}")
            time.sleep(0.05)
        time.sleep(1.5)
        victims = _pids("vibro_fit.trajectory_fitter_node", ros_domain)
        assert len(victims) == 1
        os.kill(victims[0], signal.SIGKILL)
        out, err = graph.communicate(timeout=200)
    finally:
        if graph.poll() is None:
            graph.kill()
            graph.communicate()
    assert "trajectory_fitter exited with -9; restarted (1/2)" in err, err  # the kill happened mid-run
    fitter_log = (tmp_path / "bag.logs" / "trajectory_fitter.log").read_text()
    assert "Traceback" not in fitter_log
    # the restarted fitter received the run from frame 0 again: the run ends with every impact
    assert graph.returncode == 0, out + err
    assert "frames in 300 / tracked 300 / lost 0" in out, out
    offline = subprocess.run([*VIBRO, "analyze", str(recording), "--out", str(tmp_path / "an"), "--no-progress",
                              "--no-report"], capture_output=True, text=True, timeout=120)
    assert offline.returncode == 0, offline.stderr
    res = subprocess.run([*VIBRO, "results", str(bag), "--out", str(tmp_path / "res")], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    a = json.loads((tmp_path / "an" / "results.json").read_text())["impacts"]
    b = json.loads((tmp_path / "res" / "results.json").read_text())["impacts"]
    assert len(a) >= 8 and len(b) == len(a), (len(a), len(b))
    for x, y in zip(a, b):
        assert x["plate"] == y["plate"] and abs(x["cor"] - y["cor"]) < 1e-6 and abs(x["t"] - y["t"]) < 1e-9
    print(f"trajectory_fitter SIGKILLed mid-run and restarted: {len(b)} of {len(a)} impacts in the bag, max "
          f"|COR - analyze| {max(abs(x['cor'] - y['cor']) for x, y in zip(a, b)):.1e}")


# ---------------------------------------------------------------- what a restarted node refuses (in-process)
@pytest.fixture
def fitter(tiny_recording: Path, ros_domain: str):
    import rclpy

    from vibro_fit.trajectory_fitter_node import TrajectoryFitter

    rclpy.init(args=["--ros-args", "-p", f"rig_file:={tiny_recording / 'rig.yaml'}", "-p", "run_id:=run_a",
                     "-p", "stream_wait_s:=0.3"])
    node = TrajectoryFitter()
    yield node
    node.destroy_node()
    rclpy.shutdown()


def _frame(k: int, run_id: str = "run_a", reference: int = 0):
    from vibro_msgs.msg import DicFrame

    return DicFrame(frame_index=k, t_s=0.25 + k / 1000.0, ball_mm=0.0, structure_mm=0.0, lost=False,
                    reference_frame_index=reference, run_id=run_id)


def _error_after_spin(node, seconds: float = 2.0) -> str:
    """Spin ``node`` until its guard has stopped it; the error it stops with ('' if none)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor()
    ex.add_node(node)
    end = time.monotonic() + seconds
    while time.monotonic() < end and not node.done.done():
        ex.spin_once(timeout_sec=0.05)
    ex.remove_node(node)
    assert rclpy.ok()
    return str(node.done.exception()) if node.done.done() else ""


@pytest.mark.parametrize("case, frames, expect", [
    # restarted after the tracker was: the history it receives begins at frame 40, the stream at frame 0
    ("history gap", [_frame(40), _frame(41)], "first frame received is 40 but the stream began at frame 0"),
    ("duplicate", [_frame(0), _frame(1), _frame(1)], "frame 1 received twice"),
    ("back", [_frame(0), _frame(17), _frame(16)], "frame 16 after frame 17"),
    ("other run", [_frame(0), _frame(1, run_id="run_b")], "a message of run 'run_b' reached this node of run 'run_a'"),
], ids=["history_gap", "duplicate", "back", "other_run"])
def test_fitter_stops_on_input_it_cannot_trust(fitter, case: str, frames: list, expect: str) -> None:
    for msg in frames:
        fitter._on_dic(msg)
    error = _error_after_spin(fitter)
    assert expect in error and "/trajectory_fitter: vibro/dic" in error, error
    fitter._on_dic(_frame(len(fitter.rows) + 50))  # nothing is accepted once stopped
    assert len(fitter.rows) <= max(m.frame_index for m in frames) + 1


def test_a_stream_that_begins_at_its_reference_frame_is_accepted(fitter) -> None:
    # frame 0 unreadable: the tracker's stream (and DIC reference) begins at frame 1; a gap later is a lost frame
    for k in (1, 2, 5, 6):
        fitter._on_dic(_frame(k, reference=1))
    assert fitter.guard.ok() and len(fitter.rows) == 7
    assert np.isnan(fitter.rows[3].ball_mm) and fitter.rows[3].lost


def test_fitter_without_its_accelerometer_history_stops(fitter) -> None:
    from vibro_msgs.msg import StreamStatus

    assert fitter.use_accel and fitter.rig.accelerometers is not None
    for k in range(5):
        fitter._on_dic(_frame(k))
    fitter._on_status(StreamStatus(stream="dic", items_sent=5, items_lost=0, finished=True, run_id="run_a"))
    time.sleep(0.35)
    assert not fitter._ready()
    assert "no accelerometer block ever arrived on vibro/accel" in str(fitter.done.exception())
