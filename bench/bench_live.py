"""Live at the camera's rate: the processing graph fed by a camera-like source, on this machine's cores.

    scripts/py bench/bench_live.py [--frames 1500] [--rates 250,500,1000] [--repeat 1] [--no-accel] \
        [--hog START_S,DURATION_S] [--busy-core] [--catch-up-ms MS]
    scripts/py bench/bench_live.py --suite     # the live goals: 1000 Hz x 5, 2000 Hz x 2, 1000 Hz + hog x 2

A camera process (bench/camera_peer.py) pre-loads a synthetic recording's frames (``vibro synth
--no-accel``, made once and cached in the temp folder) as raw mono8 sensor_msgs/Image messages and
publishes them on camera/image_raw at a fixed rate, stamped with each frame's data time, with best-effort
sensor QoS, as a driver does. The processing nodes run as launch starts them for a live camera
(graph_spec.launch_nodes(live=True): no file source, vibro/frames remapped to the camera topic,
dic_tracker with live_camera, nodes stay up), fresh for every rate, on a private ROS_DOMAIN_ID. A probe
process (bench/live_probe.py) records every DicFrame and ImpactEstimate as it arrives. Per rate:

- achieved publish rate; frames/s tracked (DicFrame arrivals); frames lost (DicFrames with lost=true
  plus frame indices that never arrived on vibro/dic); lag of each DicFrame behind its image;
- per impact, the latency of its first streamed (final=false) estimate on vibro/impacts, from the wall
  time the camera published the frame at the impact time, against the flight after it (the camera's
  wall time from that frame to the frame at the next impact: one flight is the least the method
  needs); the excess over one flight is the graph's own delay (goal: under 5 ms);
- each process's CPU ms/frame while streaming (/proc, bench/proc_cpu.py).

Baseline in the same run: the in-process cost of one frame through dic_tracker (the serialized Image read in
place and its pixels converted to float32, + DIC), whose inverse is the one-core ceiling of the tracker; the
tracked rate is reported against it. Image deserialization (the tracker's path before issue 41) is given beside it.

Live accelerometers (default; ``--no-accel``: camera only): a DAQ process (bench/daq_peer.py) plays the
recording's accel.csv as 20 ms AccelBlocks at 50 kHz on the camera's schedule (``--start-at-unix-s`` shared
with the camera; at a camera rate above the fps both run faster by the same factor), stamped on the lab clock;
impact_detector and trajectory_fitter read them (launch_nodes ``accel_topic``).

Start: the camera and the DAQ start once dic_tracker logs ``ready`` (reference loaded, tracker warm, its reader
matched) and the probe listens; frames published before that moment would be counted apart ("before the graph was
ready") and not as losses. Per run: images published / received / tracked, lost after ready (skipped by the
catch-up, never received, missing on vibro/dic) and whether in blocks (longest run of consecutive lost frames);
``--hog START_S,DURATION_S``: a CPU hog process pinned to core 0 from START_S after the camera's first frame for
DURATION_S, and when tracking recovered after it stopped (the first frame published after the hog whose DicFrame
lag is back under max(5 ms, 2 x the median lag before the hog), from the hog's end). ``--repeat N``: N runs per
rate, fresh nodes each. ``--busy-core``: a process spinning on core 0 for each whole run (started before the nodes,
killed after them: another program keeping one of the two cores busy). ``--tracker-pythonpath DIR``: dic_tracker
runs the vibro_dic package in DIR (a copy with an earlier dic_tracker_node.py: an A/B of the node in one session).
Per run also the load average before and after it, the machine's busy cores while streaming and the CPU of
the other processes (neither the graph's nor the bench's: others' work on a shared machine) in that time.
Nothing is asserted: the numbers go to stdout and bench/results/live.json (every run).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))
sys.path.insert(0, str(ROOT / "tests"))
from proc_cpu import MACHINE, OTHERS, CpuSampler  # noqa: E402

DOMAIN = os.environ.get("VIBRO_BENCH_DOMAIN", "79")
CAMERA_TOPIC = "camera/image_raw"
SEED = 21
GOAL_RATE_HZ = 1000.0
GOAL_EXCESS_S = 0.005
#: give dic_tracker frame 0 as its reference file (built before the camera starts); --first-image-reference: not
WITH_REFERENCE = "--first-image-reference" not in sys.argv
#: dic_tracker parameters set from the command line (--catch-up-ms), on top of the launch file's
TRACKER_PARAMETERS: dict[str, float] = {}
#: --tracker-pythonpath: a folder put first on dic_tracker's PYTHONPATH (another vibro_dic, for an A/B)
TRACKER_PATH = {"dir": ""}
#: (s) from the peers' ready files to the camera's frame 0 (--camera-lead-s). A lab triggers a camera whose driver
#: has been up for a while; a camera process just started blocked in its first publish calls (once at frame 1271),
#: waiting (under 0.6 ms of CPU in 75-333 ms, no GC): with 0.3 s, 2 of 4 runs of 1500 frames lost 94 / 476 images to
#: a 75-80 ms first publish and a 333 ms one at frame 374; with 2 s, 0 of 4 stalled (lost 1 / 0 / 0 / 0)
CAMERA_LEAD = {"s": 2.0}
#: the camera process's own environment on top of the run's (--camera-shm-segment-mb: its Fast DDS profile)
CAMERA_ENV: dict[str, str] = {}
CAMERA_PROFILE = """<?xml version="1.0" encoding="UTF-8"?>
<!-- bench_live --camera-shm-segment-mb: the camera driver's shared-memory segment (Fast DDS's default is 512 KB,
     6 images of 160 x 480 px) -->
<dds xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <profiles>
    <transport_descriptors>
      <transport_descriptor><transport_id>camera_shm</transport_id><type>SHM</type>
        <segment_size>{segment_bytes}</segment_size></transport_descriptor>
      <transport_descriptor><transport_id>camera_udp</transport_id><type>UDPv4</type></transport_descriptor>
    </transport_descriptors>
    <participant profile_name="camera_driver" is_default_profile="true">
      <rtps><userTransports><transport_id>camera_shm</transport_id><transport_id>camera_udp</transport_id>
      </userTransports><useBuiltinTransports>false</useBuiltinTransports></rtps>
    </participant>
  </profiles>
</dds>
"""
#: DAQ of the synthetic rig (vibro synth: 50 kHz), block of 20 ms
ACCEL_RATE_HZ = 50_000.0
BLOCK_SAMPLES = 1000
#: a frame is "back" after a hog when its DicFrame lag is under max(this, 2 x the median lag before the hog)
RECOVERED_LAG_S = 0.005
#: dic_tracker's status of a frame slot whose image never arrived
NOT_RECEIVED = "no image received"


def cached_recording(frames: int, accel: bool = True) -> Path:
    """A synthetic recording of ``frames`` frames (1000 fps; with ``accel`` its 50 kHz accel.csv), made once per
    temp folder."""
    rec = Path(tempfile.gettempdir()) / "vibro_bench_live" / f"rec_{frames}_seed{SEED}{'_accel' if accel else ''}"
    truth = rec.parent / f"{rec.name}.truth.json"
    if not (truth.is_file() and (rec / "rig.yaml").is_file()):
        rec.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, "-m", "vibro_app.cli", "synth", *([] if accel else ["--no-accel"]),
                        "--frames", str(frames), "--seed", str(SEED), "--out", str(rec), "--overwrite",
                        "--no-progress"], check=True)
    return rec


def tracker_cost_ms(rec: Path, n: int = 300) -> dict[str, float]:
    """ms/frame of dic_tracker's work in one process: the image read in place (``image_raw_decode_ms``), DIC
    (IC-GN), and the Image deserialization of the path before issue 41."""
    from bench_graph import stage_costs

    costs = stage_costs(rec, n)
    out = {k: costs[k] for k in ("image_deserialize_ms", "dic_icgn_ms")}
    out["image_raw_decode_ms"] = raw_decode_ms(rec, n)
    return out


def raw_decode_ms(rec: Path, n: int) -> float:
    """ms/frame of what dic_tracker does with a serialized image before the DIC since issue 41: read it in place
    (vibro_dic.raw_image) and convert its pixels into one float32 buffer."""
    from rclpy.serialization import serialize_message

    from vibro_dic.frame_source_node import image_message
    from vibro_dic.raw_image import decode_image
    from vibro_io.recording import open_recording

    wire = [serialize_message(image_message(f, "camera")) for _, f in zip(range(n), open_recording(rec).frames)]
    buf = np.empty(decode_image(wire[0]).pixels().shape, dtype=np.float32)
    t = time.perf_counter()
    for w in wire:
        np.copyto(buf, decode_image(w).pixels())
    return 1e3 * (time.perf_counter() - t) / len(wire)


def start_nodes(rec: Path, folder: Path, env: dict[str, str], accel: bool
                ) -> tuple[dict[str, subprocess.Popen], int]:
    """The live processing nodes, started as ros2 launch starts them (tests/launch_like.py), and the lab-clock
    origin (ns) they were given: the camera must stamp its frames on it, as a driver on the lab's clock does."""
    from launch_like import launch_command

    from vibro_bringup.graph_spec import LiveDaq, RunSetup, launch_nodes, write_reference_frame

    procs = {}
    # frame 0 as the tracker's reference file, as docs/live.md asks of a lab: the tracker is then built before
    # the camera starts and says "ready"
    reference = write_reference_frame(rec, folder / "reference_frame0.png") if WITH_REFERENCE else None
    nodes = launch_nodes(rec, None, live=True, camera_topic=CAMERA_TOPIC, setup=RunSetup(reference_image=reference),
                         daq=LiveDaq(topic="vibro/accel", rate_hz=ACCEL_RATE_HZ) if accel else None)
    origins = {int(n.parameters["time_origin_unix_ns"]) for n in nodes if "time_origin_unix_ns" in n.parameters}
    if len(origins) != 1:
        raise SystemExit(f"the live nodes were given {len(origins)} lab-clock origins: {sorted(origins)}")
    for n in nodes:
        if n.spec.name == "dic_tracker":
            n.parameters.update(TRACKER_PARAMETERS)
        params = folder / f"{n.spec.name}.params.yaml"
        params.write_text(yaml.safe_dump({"/**": {"ros__parameters": n.parameters}}))
        node_env = env
        if n.spec.name == "dic_tracker" and TRACKER_PATH["dir"]:
            node_env = {**env, "PYTHONPATH": os.pathsep.join(p for p in (TRACKER_PATH["dir"], env.get("PYTHONPATH"))
                                                              if p)}
        with (folder / f"{n.spec.name}.log").open("w") as log:
            procs[n.spec.name] = subprocess.Popen(launch_command(n, params), stdout=log,
                                                  stderr=subprocess.STDOUT, env=node_env)
    return procs, origins.pop()


def stop(procs: dict[str, subprocess.Popen]) -> dict[str, int]:
    """SIGINT every process, then kill what is left after 10 s; their exit codes."""
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(2)
    deadline = time.monotonic() + 10.0
    for p in procs.values():
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    return {name: p.returncode for name, p in procs.items()}


#: ``--busy-core``: the core the spinner is pinned to (another program keeping one of the two cores busy)
BUSY = {"core": None}


@contextlib.contextmanager
def busy_core(cpu: int | None, env: dict[str, str]):
    """A process spinning on core ``cpu`` while the block runs, killed when it ends however it ends
    (``--busy-core``: another program busy for the whole run; None: none), at the nodes' priority; named
    ``busy_core`` so that its CPU is sampled beside theirs."""
    if cpu is None:
        yield None
        return
    code = f"import os; os.sched_setaffinity(0, {{{cpu}}})\nwhile True: pass"
    spinner = subprocess.Popen([sys.executable, "-c", code, "__node:=busy_core"], env=env)
    try:
        yield spinner
    finally:
        spinner.kill()
        spinner.wait()


def hog(cpu: int, seconds: float) -> subprocess.Popen:
    """A process spinning on core ``cpu`` for ``seconds`` (a busy loop: another program on the lab PC)."""
    code = (f"import os, time; os.sched_setaffinity(0, {{{cpu}}}); end = time.monotonic() + {seconds}\n"
            "while time.monotonic() < end: pass")
    return subprocess.Popen([sys.executable, "-c", code])


def run_rate(rec: Path, rate_hz: float, folder: Path, env: dict[str, str], accel: bool,
             hog_window: tuple[float, float] | None) -> tuple[dict, dict, dict[str, float], dict]:
    """One live run at ``rate_hz``: (camera log, probe log, CPU s per process while streaming, run facts: the
    wall time the graph said ready, the hog's window, the DAQ log)."""
    folder.mkdir(parents=True)
    probe_out, ready, cam_out, daq_out = folder / "probe.json", folder / "probe.ready", folder / "camera.json", \
        folder / "daq.json"
    facts: dict = {"load_average_before": [round(x, 2) for x in os.getloadavg()]}
    with busy_core(BUSY["core"], env), CpuSampler(DOMAIN, machine=True) as sampler:
        nodes, origin_ns = start_nodes(rec, folder, env, accel)
        with (folder / "probe.log").open("w") as log:
            probe = subprocess.Popen([sys.executable, str(BENCH / "live_probe.py"), str(probe_out), str(ready),
                                      "--ros-args", "-r", "__node:=bench_probe"], stdout=log,
                                     stderr=subprocess.STDOUT, env=env)
        try:
            deadline = time.monotonic() + 60.0
            tracker_log = folder / "dic_tracker.log"
            # the camera starts once the probe listens and the tracker says it is ready (a lab's trigger)
            while not ready.exists() or (WITH_REFERENCE and "ready: reference" not in
                                         tracker_log.read_text(errors="replace")):
                dead = {n: p.returncode for n, p in {**nodes, "probe": probe}.items() if p.poll() is not None}
                if dead or time.monotonic() > deadline:
                    raise SystemExit(f"live graph did not come up at {rate_hz:g} Hz (exited: {dead}); logs in {folder}")
                time.sleep(0.1)
            facts["ready_at_s"] = time.time()
            fps = 1000.0
            # both peers load, match their readers and say so; then they get one start time (camera time t0)
            start_file = folder / "start"
            common = ["--time-origin-ns", str(origin_ns), "--start-file", str(start_file)]
            peers = {}
            if accel:
                with (folder / "daq.log").open("w") as log:
                    peers["daq"] = subprocess.Popen(
                        [sys.executable, str(BENCH / "daq_peer.py"), str(rec), str(daq_out), "--speed",
                         str(rate_hz / fps), "--block-samples", str(BLOCK_SAMPLES), *common, "--min-subscribers",
                         "2", "--ready-file", str(folder / "daq.ready"), "--ros-args", "-r",
                         "__node:=daq_driver"], stdout=log, stderr=subprocess.STDOUT, env=env)
            with (folder / "camera.log").open("w") as log:
                peers["camera"] = subprocess.Popen(
                    [sys.executable, str(BENCH / "camera_peer.py"), str(rec), str(cam_out), "--rate-hz", str(rate_hz),
                     *common, "--ready-file", str(folder / "camera.ready"), "--ros-args", "-r",
                     "__node:=camera_driver"], stdout=log, stderr=subprocess.STDOUT, env={**env, **CAMERA_ENV})
            waiting = [folder / f"{n}.ready" for n in peers]
            # and the tracker has matched the camera's writer (the writer seeing the reader is not enough: a reader
            # drops samples of a writer it has not matched yet; once 226 images were lost so at the start)
            while not all(f.exists() for f in waiting) or "image publisher matched" not in tracker_log.read_text(
                    errors="replace"):
                failed = {n: p.returncode for n, p in peers.items() if p.poll() is not None}
                if failed or time.monotonic() > deadline + 60:
                    raise SystemExit(f"peers not ready at {rate_hz:g} Hz (exited: {failed}); logs in {folder}")
                time.sleep(0.02)
            start = time.time() + CAMERA_LEAD["s"]
            (folder / "start.tmp").write_text(f"{start:.6f}")
            (folder / "start.tmp").rename(start_file)
            if hog_window is not None:
                delay = start + hog_window[0] - time.time()
                if delay > 0:
                    time.sleep(delay)
                facts["hog_s"] = [time.time(), time.time() + hog_window[1]]
                hog(0, hog_window[1]).wait()
            for name, p in peers.items():
                if p.wait(timeout=300) != 0:
                    raise SystemExit(f"{name} peer failed at {rate_hz:g} Hz: {(folder / f'{name}.log').read_text()}")
            probe.wait(timeout=180)
            died = {n: p.returncode for n, p in nodes.items() if p.poll() is not None}
        finally:
            stop({**nodes, "probe": probe})
        cam = json.loads(cam_out.read_text())
        seen = json.loads(probe_out.read_text())
        end = max([a for a, *_ in seen["dic"]], default=cam["published_at_s"][-1])
        cpu = sampler.cpu_between(cam["published_at_s"][0], end)
        facts["others_busiest_cpu_s"] = sampler.busiest_others(cam["published_at_s"][0], end)
    facts["load_average_after"] = [round(x, 2) for x in os.getloadavg()]
    # the machine's busy CPU while streaming, and that of the processes neither the graph's nor the bench's
    # (/proc/stat's tick counts: only roughly comparable with the processes' own CPU times)
    window_s = max(end - cam["published_at_s"][0], 1e-9)
    facts["machine_busy_cores"] = cpu.pop(MACHINE, math.nan) / window_s
    facts["others_busy_cores"] = cpu.pop(OTHERS, math.nan) / window_s
    if died:
        raise SystemExit(f"node(s) exited while streaming at {rate_hz:g} Hz: {died}; logs in {folder}")
    if accel:
        facts["daq"] = json.loads(daq_out.read_text())
    return cam, seen, cpu, facts


def runs_of(flags: list[bool]) -> list[int]:
    """Lengths of the runs of consecutive True in ``flags``."""
    out, n = [], 0
    for f in flags:
        if f:
            n += 1
        elif n:
            out.append(n)
            n = 0
    if n:
        out.append(n)
    return out


def after_ready(cam: dict, seen: dict, facts: dict, truth_impacts_s: np.ndarray, t0_s: float, fps: float,
                offset_s: float) -> dict:
    """Counts over the frames published after the graph said ready (those before, apart), the losses' reasons and
    blocks, the accelerometer impacts against the truth, and the recovery after a hog."""
    ready_at = facts["ready_at_s"]
    published = dict(zip(cam["frame_index"], cam["published_at_s"]))
    before = sorted(k for k, t in published.items() if t < ready_at)
    after = sorted(k for k, t in published.items() if t >= ready_at)
    first: dict[int, tuple[float, bool, str]] = {}
    for arrived, k, lost, status in seen["dic"]:
        first.setdefault(int(k), (arrived, bool(lost), status))
    lost_flags = [k not in first or first[k][1] for k in after]
    reasons: dict[str, int] = {}
    for k in after:
        why = "missing on vibro/dic" if k not in first else (first[k][2].split(":")[0] if first[k][1] else None)
        if why:
            reasons[why] = reasons.get(why, 0) + 1
    blocks = runs_of(lost_flags)
    out = {"images_published": len(published), "published_before_ready": len(before),
           "published_after_ready": len(after),
           "images_received_after_ready": sum(1 for k in after if k in first and not (
               first[k][1] and first[k][2].startswith(NOT_RECEIVED))),
           "tracked_after_ready": sum(1 for k in after if k in first and not first[k][1]),
           "lost_after_ready": int(sum(lost_flags)), "lost_reasons": reasons,
           "lost_runs": len(blocks), "longest_lost_run": max(blocks, default=0),
           "lost_in_blocks": bool(blocks and max(blocks) > 3)}
    if "daq" in facts:
        got = np.array(sorted(t for _, _, t in seen.get("accel_impacts", [])))
        end_cam = t0_s + (max(published) + 1) / fps
        daq_end = facts["daq"]["block_index"][-1] + 1 if facts["daq"]["block_index"] else 0
        truth = truth_impacts_s[truth_impacts_s + offset_s < end_cam - 0.06]
        err = [float(got[np.argmin(np.abs(got - (t + offset_s)))] - (t + offset_s)) for t in truth] if len(got) else []
        out["accel"] = {"blocks_sent": len(facts["daq"]["block_index"]), "last_block": daq_end - 1,
                        "impacts_streamed": int(len(got)), "impacts_in_truth": int(len(truth)),
                        "impacts_within_0_1_ms": int(sum(-2e-5 <= e <= 1e-4 for e in err)),
                        "onset_minus_truth_us": {"median": 1e6 * float(np.median(err)) if err else math.nan,
                                                 "max": 1e6 * float(np.max(np.abs(err))) if err else math.nan}}
    if "hog_s" in facts:
        h0, h1 = facts["hog_s"]
        lag = [(published[k], first[k][0] - published[k]) for k in after if k in first and not first[k][1]]
        before_lag = [x for t, x in lag if t < h0]
        limit = max(RECOVERED_LAG_S, 2 * float(np.median(before_lag)) if before_lag else 0.0)
        back = next((t + x for t, x in lag if t >= h1 and x <= limit), None)
        during = [k for k in after if h0 <= published[k] < h1]
        out["hog"] = {"window_s": [h0 - published[after[0]] if after else math.nan, h1 - h0],
                      "lost_during": int(sum(1 for k in during if k not in first or first[k][1])),
                      "frames_during": len(during), "recovered_lag_limit_ms": 1e3 * limit,
                      "recovered_after_hog_ms": 1e3 * (back - h1) if back is not None else None}
    return out


def frame_of(t_s: float, t0_s: float, fps: float) -> int:
    """The first frame index whose data time is at or after ``t_s``."""
    return int(math.ceil((t_s - t0_s) * fps - 1e-6))


def summarize(rate_hz: float, cam: dict, seen: dict, cpu: dict[str, float], truth_impacts_s: np.ndarray,
              t0_s: float, fps: float) -> dict:
    """Per-rate numbers: rates, loss, DicFrame lag, impact latency against one flight, CPU ms/frame."""
    published = dict(zip(cam["frame_index"], cam["published_at_s"]))
    pub_t = np.array(cam["published_at_s"])
    n = len(pub_t)
    first_dic: dict[int, tuple[float, bool]] = {}
    not_received = 0  # lost=true because the tracker never got the image (dropped on the way)
    for arrived, k, lost, status in seen["dic"]:
        if int(k) not in first_dic and lost and status.startswith(NOT_RECEIVED):
            not_received += 1
        first_dic.setdefault(int(k), (arrived, bool(lost)))
    missing = sorted(set(published) - set(first_dic))
    lost_flag = sorted(k for k, (_, lost) in first_dic.items() if lost and k in published)
    arrivals = np.array(sorted(a for a, _ in first_dic.values()))
    lag_ms = np.array([1e3 * (a - published[k]) for k, (a, _) in first_dic.items() if k in published])
    tracked = sum(1 for k, (_, lost) in first_dic.items() if not lost and k in published)
    streamed: dict[int, tuple[float, float]] = {}
    for arrived, idx, t_s, final in seen["impacts"]:
        if not final:
            streamed.setdefault(int(idx), (arrived, float(t_s)))
    latency, flight, excess = [], [], []
    for arrived, t_s in streamed.values():
        later = truth_impacts_s[truth_impacts_s > t_s + 0.003]
        k, k_next = frame_of(t_s, t0_s, fps), frame_of(float(later[0]), t0_s, fps) if len(later) else None
        if k not in published or k_next not in published:
            continue
        latency.append(arrived - published[k])
        flight.append(published[k_next] - published[k])
        excess.append(latency[-1] - flight[-1])
    span = arrivals[-1] - arrivals[0] if len(arrivals) > 1 else math.nan
    window = (arrivals[-1] if len(arrivals) else pub_t[-1]) - pub_t[0]
    per_frame = {k: 1e3 * v / n for k, v in sorted(cpu.items(), key=lambda kv: -kv[1])}
    ms = lambda xs, f: 1e3 * float(f(xs)) if len(xs) else math.nan  # noqa: E731
    return {
        "target_rate_hz": rate_hz,
        "frames_published": n,
        "publish_rate_hz": (n - 1) / (pub_t[-1] - pub_t[0]),
        "publish_late_max_ms": 1e3 * float(np.max(np.diff(pub_t))) - 1e3 / rate_hz,
        # the camera process itself stalled (a late frame goes out at once: a burst follows); (frame, ms)
        "camera_publish_calls_over_5_ms": [[c["frame"], c["ms"]] for c in cam["slow_publish_calls"]],
        # and per such call: the camera thread's CPU time in it, its context switches, Python's GC time in it
        "camera_slow_publish_calls": cam["slow_publish_calls"],
        "frames_per_s_tracked": tracked / span if span > 0 else math.nan,  # lost=false DicFrames only
        "dic_frames_per_s": (len(arrivals) - 1) / span if span > 0 else math.nan,  # every answered slot
        "frames_tracked": tracked,
        "frames_lost_flagged": len(lost_flag),
        "frames_lost_image_not_received": not_received,
        "first_lost_flagged": lost_flag[:10],
        "frames_missing": len(missing),
        "frames_lost_total": len(lost_flag) + len(missing),
        "first_missing": missing[:10],
        "dic_lag_ms": {"median": float(np.median(lag_ms)), "p99": float(np.percentile(lag_ms, 99)),
                       "max": float(np.max(lag_ms)),
                       "last_100_median": float(np.median(lag_ms[-100:]))} if len(lag_ms) else {},
        "impacts_streamed": len(streamed),
        "impacts_in_truth": int(np.sum(truth_impacts_s <= (max(published) - 0) / fps + t0_s)),
        "impact_latency_ms": {"median": ms(latency, np.median), "max": ms(latency, np.max)},
        "flight_ms": {"median": ms(flight, np.median), "min": ms(flight, np.min)},
        "latency_minus_flight_ms": {"median": ms(excess, np.median), "max": ms(excess, np.max)},
        "cpu_ms_per_frame": per_frame,
        "cpu_ms_per_frame_graph": sum(v for k, v in per_frame.items()
                                      if k not in ("camera_driver", "bench_probe", "busy_core")),
        "cpu_utilisation_of_cores": sum(cpu.values()) / (window * (os.cpu_count() or 1)),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1500)
    parser.add_argument("--rates", default="250,500,1000", help="camera rates to run (Hz), comma-separated")
    parser.add_argument("--repeat", type=int, default=1, help="runs per rate, fresh nodes each")
    parser.add_argument("--no-accel", action="store_true", help="camera only: no DAQ peer, no impact_detector")
    parser.add_argument("--hog", default="", help="START_S,DURATION_S: a CPU hog on core 0 from START_S after the "
                                                  "camera's first frame, for DURATION_S")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "live.json")
    parser.add_argument("--catch-up-ms", type=float, default=None,
                        help="dic_tracker's catch_up_ms (default: the node's): the time within which it works off a "
                             "backlog, thinning it when its work per frame cannot (0: always the newest image)")
    parser.add_argument("--camera-lead-s", type=float, default=CAMERA_LEAD["s"],
                        help=f"seconds from the peers being ready to the camera's frame 0 (default {CAMERA_LEAD['s']})")
    parser.add_argument("--camera-shm-segment-mb", type=float, default=None,
                        help="the camera process's Fast DDS shared-memory segment (MB; default: Fast DDS's 512 KB)")
    parser.add_argument("--first-image-reference", action="store_true",
                        help="give dic_tracker no reference file: it builds its tracker on the first image (A/B of "
                             "the start-up)")
    parser.add_argument("--busy-core", action="store_true",
                        help="a process spinning on core 0 for each whole run (another program keeping one of the "
                             "cores busy), started before the nodes and killed after them")
    parser.add_argument("--tracker-pythonpath", default="",
                        help="a folder put first on dic_tracker's PYTHONPATH: another vibro_dic package there is the "
                             "one it runs (A/B of the tracker node against a copy of an earlier version)")
    parser.add_argument("--suite", action="store_true",
                        help="the live goals' three scenarios in one run, all to --out: 1000 Hz x 5, 2000 Hz x 2, "
                             "1000 Hz with a 0.3 s hog on core 0 x 2 (--rates/--repeat/--hog are then ignored)")
    args = parser.parse_args()
    if not args.camera_lead_s > 0:
        parser.error("--camera-lead-s must be > 0")
    CAMERA_LEAD["s"] = args.camera_lead_s
    if args.busy_core:
        BUSY["core"] = 0
    TRACKER_PATH["dir"] = str(Path(args.tracker_pythonpath).resolve()) if args.tracker_pythonpath else ""
    if args.camera_shm_segment_mb is not None:
        if not args.camera_shm_segment_mb > 0:
            parser.error("--camera-shm-segment-mb must be > 0")
        profile = Path(tempfile.gettempdir()) / "vibro_bench_live" / "camera_profile.xml"
        profile.parent.mkdir(parents=True, exist_ok=True)
        profile.write_text(CAMERA_PROFILE.format(segment_bytes=int(args.camera_shm_segment_mb * 2**20)))
        CAMERA_ENV["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)
    if args.catch_up_ms is not None:
        TRACKER_PARAMETERS["catch_up_ms"] = float(args.catch_up_ms)
    if args.suite:
        scenarios = [run_scenario(args, [rate], repeat, hog) for rate, repeat, hog in SUITE]
        result: dict = {"suite": [{"rate_hz": r, "repeat": n, "hog": h} for r, n, h in SUITE],
                        "command": " ".join(sys.argv), "scenarios": scenarios}
    else:
        hog_window = tuple(float(x) for x in args.hog.split(",")) if args.hog else None
        result = run_scenario(args, [float(r) for r in args.rates.split(",")], args.repeat, hog_window)
    out = args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


#: ``--suite``: (camera rate Hz, runs, hog (start s, duration s) or None)
SUITE = ((1000.0, 5, None), (2000.0, 2, None), (1000.0, 2, (0.5, 0.3)))


def run_scenario(args: argparse.Namespace, rates: list[float], repeat: int, hog_window: tuple | None) -> dict:
    """``repeat`` runs at each of ``rates`` (fresh nodes each), printed; the scenario's result."""
    from vibro_io.rig import load_rig

    accel = not args.no_accel
    rec = cached_recording(args.frames, accel)
    cam = load_rig(rec / "rig.yaml").camera
    truth = json.loads((rec.parent / f"{rec.name}.truth.json").read_text())
    truth_impacts_s = np.array(sorted(i["t"] for i in truth["impacts"]))
    env = dict(os.environ, ROS_DOMAIN_ID=DOMAIN, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    result: dict = {"frames": args.frames, "cores": os.cpu_count(), "goal_rate_hz": GOAL_RATE_HZ,
                    "goal_latency": "one flight + 5 ms", "executor": os.environ.get("VIBRO_EXECUTOR", "events"),
                    "recording": f"vibro synth {'' if accel else '--no-accel '}--frames {args.frames} --seed {SEED}",
                    "accelerometers": f"daq_peer {ACCEL_RATE_HZ:g} Hz, {BLOCK_SAMPLES} samples a block" if accel
                    else None, "hog": {"start_s": hog_window[0], "duration_s": hog_window[1], "core": 0}
                    if hog_window else None, "command": " ".join(sys.argv),
                    "dic_tracker_parameters": dict(TRACKER_PARAMETERS), "camera_env": dict(CAMERA_ENV),
                    "camera_lead_s": CAMERA_LEAD["s"], "busy_core": BUSY["core"],
                    "tracker_pythonpath": TRACKER_PATH["dir"]}
    result["tracker_in_process_ms_per_frame"] = tracker_cost_ms(rec)
    # the tracker's own work per image now: read in place + DIC (the deserialization is the path before issue 41)
    one_core = 1e3 / (result["tracker_in_process_ms_per_frame"]["image_raw_decode_ms"]
                      + result["tracker_in_process_ms_per_frame"]["dic_icgn_ms"])
    result["tracker_one_core_ceiling_frames_per_s"] = one_core
    runs = []
    logs = rec.parent / "runs"  # kept for a look after the run; replaced by the next one
    shutil.rmtree(logs, ignore_errors=True)
    for rate in rates:
        for rep in range(repeat):
            camera_log, seen, cpu, facts = run_rate(rec, rate, logs / f"rate_{rate:g}_{rep}", env, accel, hog_window)
            run = summarize(rate, camera_log, seen, cpu, truth_impacts_s, cam.t0_s, cam.fps)
            run["repeat"] = rep
            run["tracked_vs_one_core_ceiling_ratio"] = run["frames_per_s_tracked"] / one_core
            run.update(after_ready(camera_log, seen, facts, truth_impacts_s, cam.t0_s, cam.fps,
                                   float(truth.get("clock_offset_s", 0.0))))
            run.update({k: facts[k] for k in ("load_average_before", "load_average_after", "machine_busy_cores",
                                              "others_busy_cores", "others_busiest_cpu_s")})
            run["busy_core"] = BUSY["core"]
            run["dic_tracker_cpu_ms_per_frame"] = run["cpu_ms_per_frame"].get("dic_tracker", math.nan)
            runs.append(run)
    result["runs"] = runs

    c = result["tracker_in_process_ms_per_frame"]
    print(f"baseline, dic_tracker's work in one process: image read in place {c['image_raw_decode_ms']:.3f} (before "
          f"issue 41 deserialized: {c['image_deserialize_ms']:.3f}) + DIC {c['dic_icgn_ms']:.3f} ms/frame = "
          f"{one_core:.0f} frames/s on one core")
    for r in runs:
        lag, lat, ex = r["dic_lag_ms"], r["impact_latency_ms"], r["latency_minus_flight_ms"]
        print(f"camera {r['target_rate_hz']:5.0f} Hz (run {r['repeat'] + 1}): published at "
              f"{r['publish_rate_hz']:6.1f} Hz, tracked "
              f"{r['frames_per_s_tracked']:6.1f} frames/s ({r['tracked_vs_one_core_ceiling_ratio']:.2f}x the one-core "
              f"ceiling), lost {r['frames_lost_total']} of {r['frames_published']} ({r['frames_lost_flagged']} "
              f"flagged lost, of which {r['frames_lost_image_not_received']} images never reached the tracker; "
              f"{r['frames_missing']} missing on vibro/dic)")
        print(f"    DicFrame lag behind its image: median {lag.get('median', math.nan):.1f} ms, p99 "
              f"{lag.get('p99', math.nan):.1f}, max {lag.get('max', math.nan):.1f}, last 100 frames "
              f"{lag.get('last_100_median', math.nan):.1f}")
        print(f"    impacts streamed {r['impacts_streamed']}: latency median {lat['median']:.1f} ms, max "
              f"{lat['max']:.1f}; flight median {r['flight_ms']['median']:.1f} ms; latency - flight median "
              f"{ex['median']:.1f} ms, max {ex['max']:.1f} (goal < {1e3 * GOAL_EXCESS_S:.0f})")
        print(f"    CPU {r['cpu_ms_per_frame_graph']:.2f} ms/frame in the graph, "
              f"{100 * r['cpu_utilisation_of_cores']:.0f} % of {os.cpu_count()} cores in all:")
        for node, v in r["cpu_ms_per_frame"].items():
            print(f"        {node:20s} {v:6.3f} ms/frame")
        if r["camera_publish_calls_over_5_ms"] or r["publish_late_max_ms"] > 5:
            print(f"    the camera process itself stalled: publish late by up to {r['publish_late_max_ms']:.1f} ms, "
                  f"publish calls over 5 ms (frame, ms) {r['camera_publish_calls_over_5_ms'][:5]}")
            for c in [c for c in r["camera_slow_publish_calls"] if c["ms"] > 20][:3]:
                print(f"        frame {c['frame']}: {c['ms']} ms in publish, {c['thread_cpu_ms']} ms of it on the CPU, "
                      f"{c['voluntary_switches']} waits, {c['involuntary_switches']} preemptions, GC {c['gc_ms']} ms")
        print(f"    after ready: {r['published_after_ready']} published ({r['published_before_ready']} before the "
              f"graph was ready), {r['tracked_after_ready']} tracked, {r['lost_after_ready']} lost "
              f"{r['lost_reasons']} in {r['lost_runs']} run(s), longest {r['longest_lost_run']}")
        if "accel" in r:
            a = r["accel"]
            print(f"    accelerometers: {a['blocks_sent']} blocks, {a['impacts_streamed']} impacts streamed, "
                  f"{a['impacts_within_0_1_ms']} of {a['impacts_in_truth']} in truth found within 0.1 ms "
                  f"(onset - truth median {a['onset_minus_truth_us']['median']:.0f} us)")
        if "hog" in r:
            h = r["hog"]
            print(f"    hog {h['window_s'][1]:.2f} s on core 0: {h['lost_during']} of {h['frames_during']} frames "
                  f"lost during it; recovered {h['recovered_after_hog_ms']} ms after it stopped "
                  f"(lag under {h['recovered_lag_limit_ms']:.1f} ms)")
    print(f"per run{' (a process spinning on core 0 throughout)' if BUSY['core'] is not None else ''}:")
    for r in runs:
        print(f"    {r['target_rate_hz']:g} Hz run {r['repeat'] + 1}: lost {r['lost_after_ready']} of "
              f"{r['published_after_ready']} {r['lost_reasons']}, impacts streamed {r['impacts_streamed']}"
              f"{' (accel ' + str(r['accel']['impacts_streamed']) + ')' if 'accel' in r else ''}, dic_tracker "
              f"{r['dic_tracker_cpu_ms_per_frame']:.3f} ms CPU/frame, load average {r['load_average_before'][0]:.2f}"
              f" -> {r['load_average_after'][0]:.2f}, others' processes {r['others_busy_cores']:.2f} cores "
              f"(machine {r['machine_busy_cores']:.2f})")
    return result


if __name__ == "__main__":
    sys.exit(main())
