"""frame_source -> dic_tracker over DDS, in separate processes, on the committed fixture."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def _start(*argv: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_frames_cross_dds_and_a_corrupt_frame_is_a_visible_gap(tiny_recording: Path, tmp_path: Path,
                                                                ros_domain: str) -> None:
    rec = tmp_path / "rec"
    shutil.copytree(tiny_recording, rec)
    (rec / "frames" / "000002.png").write_bytes(b"not a png")
    echo = _start(str(HERE / "ros_echo.py"), "vibro_msgs/msg/DicFrame", "vibro/dic", "--count", "5", "--seconds", "60")
    # the tracker holds its results until both readers (this echo, frame_source's acknowledgements) have matched
    tracker = _start("-m", "vibro_dic.dic_tracker_node", "--ros-args", "-p", f"rig_file:={rec / 'rig.yaml'}",
                     "-p", "readers:=[vibro_test_echo, frame_source]")
    try:
        assert echo.stdout.readline().strip() == "READY"
        source = subprocess.run(
            # frame_source waits for the tracker's acknowledgements, which the tracker holds until the echo has
            # matched too: on a loaded machine that can take longer than the default linger of 3 s, after which
            # the source would leave and the tracker would wait for it forever
            [sys.executable, "-m", "vibro_dic.frame_source_node", "--ros-args", "-p", f"recording:={rec}",
             "-p", "linger_s:=50.0"],
            capture_output=True, text=True, timeout=60)
        out, _ = echo.communicate(timeout=60)
    finally:
        tracker.send_signal(signal.SIGINT)
        _, tracker_err = tracker.communicate(timeout=20)
        echo.kill()
    assert source.returncode == 0, source.stderr
    assert out.count("{") >= 5, f"echo got {out!r}\nsource:\n{source.stderr}\ntracker:\n{tracker_err}"
    assert "frame 2 not published" in source.stderr and "000002.png" in source.stderr
    rows = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    assert [r["frame_index"] for r in rows] == [0, 1, 2, 3, 4]
    assert rows[2]["lost"] and "no image received" in rows[2]["status"] and math.isnan(rows[2]["ball_mm"])
    # the fixture's ball half moves down 2 whole px per frame at 0.05 mm/px: -0.1 mm per frame;
    # integer shifts of a noise-free pattern leave only interpolation error, well under 0.02 px = 0.001 mm
    for r in rows:
        if r["frame_index"] != 2:
            assert not r["lost"]
            assert abs(r["ball_mm"] - (-0.1 * r["frame_index"])) < 1e-3
            assert abs(r["structure_mm"]) < 1e-3
            assert r["ball_valid_points"] == r["ball_mesh_points"] > 0
    assert tracker.returncode == 0 and "Traceback" not in tracker_err


def _first_stderr_line(proc: subprocess.Popen, timeout_s: float) -> str:
    """The first line ``proc`` writes to stderr (text pipe), waiting at most ``timeout_s``."""
    import selectors

    sel = selectors.DefaultSelector()
    sel.register(proc.stderr, selectors.EVENT_READ)
    try:
        if not sel.select(timeout=timeout_s):
            proc.kill()
            pytest.fail(f"no log line within {timeout_s} s (exit code {proc.poll()})")
        return proc.stderr.readline()
    finally:
        sel.close()


@pytest.mark.parametrize("executor", ["events", "single"])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_nodes_stop_cleanly_on_sigint_and_sigterm(tiny_recording: Path, ros_domain: str, executor: str,
                                                 sig: signal.Signals) -> None:
    # rclpy 7.1's EventsExecutor.spin() never returns after SIGINT; run_node must still stop
    tracker = subprocess.Popen([sys.executable, "-m", "vibro_dic.dic_tracker_node", "--ros-args",
                                "-p", f"rig_file:={tiny_recording / 'rig.yaml'}"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={**os.environ, "VIBRO_EXECUTOR": executor})
    # the signal must reach a running node, not an interpreter still importing numpy (2 s was too short on a
    # loaded machine): wait for the node's first log line, written once it exists
    first = _first_stderr_line(tracker, timeout_s=60)
    time.sleep(0.5)
    tracker.send_signal(sig)
    try:
        _, err = tracker.communicate(timeout=20)
        err = first + err
    except subprocess.TimeoutExpired:
        tracker.kill()
        pytest.fail(f"dic_tracker ({executor} executor) did not stop within 20 s of {sig.name}")
    assert tracker.returncode == 0 and "Traceback" not in err


def test_unknown_executor_is_one_clear_line(tiny_recording: Path, ros_domain: str) -> None:
    res = subprocess.run([sys.executable, "-m", "vibro_dic.dic_tracker_node", "--ros-args",
                          "-p", f"rig_file:={tiny_recording / 'rig.yaml'}"], capture_output=True, text=True,
                         timeout=30, env={**os.environ, "VIBRO_EXECUTOR": "turbo"})
    assert res.returncode == 2
    assert "VIBRO_EXECUTOR='turbo'" in res.stderr and "Traceback" not in res.stderr


def test_missing_parameter_is_one_clear_line(ros_domain: str) -> None:
    res = subprocess.run([sys.executable, "-m", "vibro_dic.dic_tracker_node"], capture_output=True, text=True,
                         timeout=30)
    assert res.returncode == 2
    assert "parameter 'rig_file' is required" in res.stderr and "Traceback" not in res.stderr


@pytest.mark.parametrize("value", ["0.0", "-0.05", ".nan"])
def test_a_texture_threshold_that_is_not_a_positive_px_is_refused(tiny_recording: Path, ros_domain: str,
                                                                   value: str) -> None:
    # NaN would pass every subset (no comparison is true), <= 0 would refuse every one as "too little texture"
    res = subprocess.run([sys.executable, "-m", "vibro_dic.dic_tracker_node", "--ros-args", "-p",
                          f"rig_file:={tiny_recording / 'rig.yaml'}", "-p", f"max_subset_sigma_px:={value}"],
                         capture_output=True, text=True, timeout=30)
    assert res.returncode == 2, res.stderr
    assert "'max_subset_sigma_px' must be a positive" in res.stderr and "Traceback" not in res.stderr


def test_a_misspelt_stream_to_keep_history_for_is_refused_not_waited_for(tiny_recording: Path,
                                                                          ros_domain: str) -> None:
    # a stream name no node ever finishes would keep the node up until the run's timeout
    res = subprocess.run([sys.executable, "-m", "vibro_dic.frame_source_node", "--ros-args", "-p",
                          f"recording:={tiny_recording}", "-p", "keep_history_until:=[dics]"],
                         capture_output=True, text=True, timeout=30)
    assert res.returncode == 2, res.stderr
    assert "keep_history_until" in res.stderr and "'dics'" in res.stderr and "Traceback" not in res.stderr


def test_diagnostics_report_lag_behind_the_camera_clock(tiny_recording: Path, ros_domain: str) -> None:
    # 5 frames of a 1000 fps camera sent at 10 frames/s: between the first and the last frame
    # 4/10 s of wall time pass for 4/1000 s of camera time, so the source runs 0.396 s behind
    # real time. The send schedule is checked by a 10 ms timer, so allow 0.08 s of jitter.
    # The echo keeps every report until the source has exited (the source reports once a second and once
    # more when it stops; how many reports fall before the last frame depends on discovery time).
    echo = _start(str(HERE / "ros_echo.py"), "diagnostic_msgs/msg/DiagnosticArray", "/diagnostics",
                  "--count", "1000", "--seconds", "60")
    try:
        assert echo.stdout.readline().strip() == "READY"
        source = subprocess.run(
            [sys.executable, "-m", "vibro_dic.frame_source_node", "--ros-args", "-p", f"recording:={tiny_recording}",
             "-p", "rate_hz:=10.0", "-p", "readers:=[vibro_test_echo]", "-p", "linger_s:=2.5"],
            capture_output=True, text=True, timeout=60)
        time.sleep(1.0)  # the stop report in flight
        echo.send_signal(signal.SIGINT)
        out, _ = echo.communicate(timeout=30)
    finally:
        echo.kill()
    assert source.returncode == 0, source.stderr
    statuses = [s for line in out.splitlines() if line.startswith("{")
                for s in json.loads(line)["status"] if s["name"].endswith("frame_source")]
    # the source lingers 2.5 s after its last frame, so reports made after the last frame exist
    values = max(({kv["key"]: kv["value"] for kv in s["values"]} for s in statuses),
                 key=lambda v: int(v.get("published_count", 0)))
    assert values["published_count"] == "5"
    assert abs(float(values["lag_s"]) - 4 * (1 / 10 - 1 / 1000)) < 0.08


def test_tracker_diagnostics_report_progress_against_the_expected_frame_count(tiny_recording: Path, tmp_path: Path,
                                                                              ros_domain: str) -> None:
    rec = tmp_path / "rec"
    shutil.copytree(tiny_recording, rec)
    n = len(list((rec / "frames").glob("*.png")))
    echo = _start(str(HERE / "ros_echo.py"), "diagnostic_msgs/msg/DiagnosticArray", "/diagnostics",
                  "--count", "1000", "--seconds", "60")
    tracker = _start("-m", "vibro_dic.dic_tracker_node", "--ros-args", "-p", f"rig_file:={rec / 'rig.yaml'}",
                     # the echo is a declared reader too: the tracker waits for it, and for its acknowledgements
                     "-p", "readers:=[frame_source,vibro_test_echo]", "-p", f"frames_expected:={n + 3}")
    try:
        assert echo.stdout.readline().strip() == "READY"
        source = subprocess.run(
            # frame_source waits for the tracker's acknowledgements, which the tracker holds until the echo has
            # matched too: on a loaded machine that can take longer than the default linger of 3 s, after which
            # the source would leave and the tracker would wait for it forever
            [sys.executable, "-m", "vibro_dic.frame_source_node", "--ros-args", "-p", f"recording:={rec}",
             "-p", "linger_s:=50.0"],
            capture_output=True, text=True, timeout=60)
        _, tracker_err = tracker.communicate(timeout=30)  # file mode: it exits once its stream has ended
        time.sleep(1.0)
    finally:
        if tracker.poll() is None:
            tracker.send_signal(signal.SIGINT)
            tracker.communicate(timeout=20)
        echo.send_signal(signal.SIGINT)
        out, _ = echo.communicate(timeout=20)
    assert source.returncode == 0, source.stderr
    assert tracker.returncode == 0 and "Traceback" not in tracker_err
    reports = [{kv["key"]: kv["value"] for kv in s["values"]}
               for line in out.splitlines() if line.startswith("{")
               for s in json.loads(line)["status"] if s["name"].endswith("dic_tracker")]
    assert reports, out[-2000:]
    done = [(int(r["frames_done"]), r["frames_expected"], r["progress"]) for r in reports if "frames_done" in r]
    # every frame slot answered, out of the count the parameter announced (n + 3: the progress is n / (n + 3))
    assert done and done[-1] == (n, str(n + 3), f"{n / (n + 3):.3f}"), done
    assert float(reports[-1]["ball_zncc_median"]) > 0.9  # a noise-free pattern shifted by whole pixels
