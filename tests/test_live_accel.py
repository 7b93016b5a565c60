"""Live accelerometers: a DAQ driver's AccelBlocks (bench/daq_peer.py) beside live DicFrames, into impact_detector
and trajectory_fitter with ``live_accel``, each a real node in its own process over DDS."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
BENCH = HERE.parent / "bench"
ORIGIN_NS = 1_764_000_000_000_000_000
#: the synthetic DAQ's clock runs this far ahead of the camera's (s)
OFFSET_S = 0.0042
FS_HZ = 50_000.0
BLOCK = 1000  # samples: 20 ms
DROPPED = (12, 13)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    from vibro_sim.synth import SynthConfig, synthesize

    rec = tmp_path_factory.mktemp("live_accel") / "rec"
    synthesize(rec, SynthConfig(frames=600, seed=5, clock_offset_s=OFFSET_S), progress=False)
    return rec


def _node(module: str, rec: Path, *params: str) -> subprocess.Popen:
    args = [sys.executable, "-m", module, "--ros-args", "-p", f"rig_file:={rec / 'rig.yaml'}",
            "-p", f"time_origin_unix_ns:={ORIGIN_NS}", "-p", "live_accel:=true", "-p", "exit_when_done:=false"]
    for p in params:
        args += ["-p", p]
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _last_statuses(diags: list) -> dict[str, tuple]:
    """Per status name, the latest status among the DiagnosticArrays received so far and its values."""
    last = {}
    for arr in diags:
        for st in arr.status:
            last[st.name] = (st, _values(st))
    return last


def test_live_blocks_give_impacts_on_the_camera_clock_and_a_lost_block_is_reported(recording: Path, tmp_path: Path,
                                                                                     ros_domain: str) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from ros_probe import Probe

    from vibro_msgs.msg import AccelImpact
    from vibro_ros.node_support import RESULTS_QOS

    truth = json.loads((recording.parent / "rec.truth.json").read_text())
    assert truth["clock_offset_s"] == OFFSET_S
    detector = _node("vibro_fit.impact_detector_node", recording, "accel_rate_hz:=50000.0")
    fitter = _node("vibro_fit.trajectory_fitter_node", recording, "accel_rate_hz:=50000.0")
    procs = [detector, fitter]
    try:
        with Probe() as probe:
            impacts = probe.subscribe(AccelImpact, "vibro/accel_impacts", RESULTS_QOS)
            diags = probe.subscribe(DiagnosticArray, "/diagnostics", 100)
            assert probe.wait_for_nodes(["/impact_detector", "/trajectory_fitter"], 60)
            # both peers on one schedule: camera time t0 at one wall time, written once both are loaded (tracked,
            # publishing) and the DAQ peer has both nodes' readers matched (a reader that matched late would start
            # mid-stream)
            ready = [tmp_path / "daq.ready", tmp_path / "dic.ready"]
            start_file = tmp_path / "start"
            common = ["--time-origin-ns", str(ORIGIN_NS), "--start-file", str(start_file)]
            daq = subprocess.Popen([sys.executable, str(BENCH / "daq_peer.py"), str(recording),
                                    str(tmp_path / "daq.json"), "--block-samples", str(BLOCK), "--drop-blocks",
                                    ",".join(map(str, DROPPED)), "--min-subscribers", "2", *common,
                                    "--ready-file", str(ready[0]), "--ros-args", "-r", "__node:=daq_driver"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            dic = subprocess.Popen([sys.executable, str(HERE / "live_dic_peer.py"), str(recording), *common,
                                    "--ready-file", str(ready[1]), "--ros-args", "-r", "__node:=dic_tracker"],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            procs += [daq, dic]
            assert probe.spin_until(lambda: all(f.exists() for f in ready) or daq.poll() is not None
                                    or dic.poll() is not None, 120)
            tmp_start = start_file.with_suffix(".tmp")
            tmp_start.write_text(f"{time.time() + 1.0:.6f}")
            tmp_start.rename(start_file)  # whole, as the peers read it
            assert probe.spin_until(lambda: daq.poll() is not None and dic.poll() is not None, 120)
            assert daq.returncode == 0, daq.stderr.read()
            assert dic.returncode == 0, dic.stderr.read()
            # the fitter has had every frame when its offset comes from the impacts both clocks saw; a loaded
            # machine gets it there later than the peers end (checked below, whatever happens here)
            probe.spin_until(lambda: _last_statuses(diags).get("/trajectory_fitter", (None, {}))[1]
                             .get("clock_offset_source", "").startswith("impacts"), 30)
            probe.spin(2.5)  # the last diagnostics (once a second)
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(2)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
    for p in (detector, fitter):
        err = p.stderr.read()
        assert p.returncode == 0 and "Traceback" not in err, err

    last = _last_statuses(diags)
    det_status, det = last["/impact_detector"]
    fit_status, fit = last["/trajectory_fitter"]

    # the stamps say the offset exactly (daq_peer stamps each block at origin + its first sample's camera time)
    assert fit.get("clock_offset_from_stamps_s"), (fit, fit_status.message)
    assert abs(float(det["clock_offset_from_stamps_s"]) - OFFSET_S) < 1e-6
    assert abs(float(fit["clock_offset_from_stamps_s"]) - OFFSET_S) < 1e-6
    # the two dropped blocks: counted lost, named, and no impact detected in them
    assert det["blocks_lost_count"] == str(len(DROPPED)) and fit["accel_blocks_lost_count"] == str(len(DROPPED))
    assert det["samples_lost_count"] == str(len(DROPPED) * BLOCK)

    sent = json.loads((tmp_path / "daq.json").read_text())["block_index"]
    lost_lo = DROPPED[0] * BLOCK / FS_HZ  # DAQ time of the lost stretch: its first sample ...
    lost_hi = (DROPPED[-1] + 1) * BLOCK / FS_HZ  # ... to the end of its last
    data_t0 = json.loads((tmp_path / "daq.json").read_text())
    assert abs(data_t0["sample_rate_hz"] - FS_HZ) < 1e-6 * FS_HZ
    from vibro_io.recording import open_recording

    acc = open_recording(recording).load_accel()
    t_first, t_end = float(acc.t_s[0]), float(acc.t_s[0]) + (max(sent) + 1) * BLOCK / FS_HZ
    lost_lo, lost_hi = t_first + lost_lo, t_first + lost_hi
    # an impact's ringing (3.1 kHz lowest mode) crosses 8 sigma within a quarter period of its first sample after
    # the impact: the onset lies between the sample grid's last point before the impact and 0.1 ms after it
    got = np.array(sorted(m.t_s for m in impacts))
    # the detector holds the last 30 ms of context + half a drive period back until more samples come
    ctx = 0.03 + 0.5 / truth["config"]["frequency_hz"]
    expected = [t + OFFSET_S for t in (i["t"] for i in truth["impacts"])
                if t_first + 0.001 < t + OFFSET_S < t_end - ctx and not lost_lo - 0.001 < t + OFFSET_S < lost_hi]
    assert len(expected) >= 8
    for t in expected:
        k = int(np.argmin(np.abs(got - t)))
        assert -1.0 / FS_HZ <= got[k] - t <= 1e-4, (t, got[k])
    assert not any(lost_lo <= t < lost_hi for t in got)  # nothing invented in the gap
    assert "12..13 lost" in det_status.message or any("12..13" in str(v) for v in det.values())
    # each impact's stamp is its camera time on the lab clock: DAQ time - offset
    for m in impacts:
        stamp_s = (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec - ORIGIN_NS) / 1e9
        assert abs(stamp_s - (m.t_s - OFFSET_S)) < 2e-6

    # the fitter: its offset refined from the impacts both clocks saw, as vibro analyze refines it
    assert fit["clock_offset_source"].startswith("impacts"), f"{fit} {fit_status.message}"
    n_matched = int(fit["clock_offset_source"].split("(")[1].split()[0])
    assert n_matched >= 4
    # median of (accelerometer onset - DIC impact time): the onset lags the impact by 0..0.1 ms (above), the DIC
    # impact time scatters by its t_std_s (tens of us at this noise); the median of a handful is within 0.15 ms
    assert abs(float(fit["clock_offset_s"]) - OFFSET_S) < 1.5e-4, fit
    assert int(fit.get("accel_impacts_count", "0")) >= len(expected)


def test_a_block_at_the_wrong_rate_is_refused_with_a_message(recording: Path, tmp_path: Path, ros_domain: str) -> None:
    detector = _node("vibro_fit.impact_detector_node", recording, "accel_rate_hz:=25000.0")
    daq = subprocess.Popen([sys.executable, str(BENCH / "daq_peer.py"), str(recording), str(tmp_path / "daq.json"),
                            "--ros-args", "-r", "__node:=daq_driver"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _, err = detector.communicate(timeout=90)
    finally:
        for p in (detector, daq):
            if p.poll() is None:
                p.kill()
                p.wait()
    assert detector.returncode == 2, err
    assert "sample_rate_hz 50000 Hz but the DAQ is stated at 25000 Hz" in err and "Traceback" not in err
