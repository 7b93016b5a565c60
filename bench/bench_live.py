"""Live at the camera's rate: the processing graph fed by a camera-like source, on this machine's cores.

    scripts/py bench/bench_live.py [--frames 1500] [--rates 250,500,1000]

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

Baseline in the same run: the in-process cost of one frame through dic_tracker (Image deserialization +
DIC), whose inverse is the one-core ceiling of the tracker; the tracked rate is reported against it.
Nothing is asserted: the numbers go to stdout and bench/results/live.json.
"""

from __future__ import annotations

import argparse
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
from proc_cpu import CpuSampler  # noqa: E402

DOMAIN = os.environ.get("VIBRO_BENCH_DOMAIN", "79")
CAMERA_TOPIC = "camera/image_raw"
SEED = 21
GOAL_RATE_HZ = 1000.0
GOAL_EXCESS_S = 0.005
#: give dic_tracker frame 0 as its reference file (built before the camera starts); --first-image-reference: not
WITH_REFERENCE = "--first-image-reference" not in sys.argv
#: dic_tracker's status of a frame slot whose image never arrived
NOT_RECEIVED = "no image received"


def cached_recording(frames: int) -> Path:
    """A video-only synthetic recording of ``frames`` frames (1000 fps), made once per temp folder."""
    rec = Path(tempfile.gettempdir()) / "vibro_bench_live" / f"rec_{frames}_seed{SEED}"
    truth = rec.parent / f"{rec.name}.truth.json"
    if not (truth.is_file() and (rec / "rig.yaml").is_file()):
        rec.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, "-m", "vibro_app.cli", "synth", "--no-accel", "--frames", str(frames),
                        "--seed", str(SEED), "--out", str(rec), "--overwrite", "--no-progress"], check=True)
    return rec


def tracker_cost_ms(rec: Path, n: int = 300) -> dict[str, float]:
    """ms/frame of dic_tracker's work in one process: Image deserialization and DIC (IC-GN)."""
    from bench_graph import stage_costs

    costs = stage_costs(rec, n)
    return {k: costs[k] for k in ("image_deserialize_ms", "dic_icgn_ms")}


def start_nodes(rec: Path, folder: Path, env: dict[str, str]) -> tuple[dict[str, subprocess.Popen], int]:
    """The live processing nodes, started as ros2 launch starts them (tests/launch_like.py), and the lab-clock
    origin (ns) they were given: the camera must stamp its frames on it, as a driver on the lab's clock does."""
    from launch_like import launch_command

    from vibro_bringup.graph_spec import launch_nodes, write_reference_frame

    procs = {}
    # frame 0 as the tracker's reference file, as docs/live.md asks of a lab: the tracker is then built before
    # the camera starts and says "ready"
    reference = write_reference_frame(rec, folder / "reference_frame0.png") if WITH_REFERENCE else None
    nodes = launch_nodes(rec, None, live=True, camera_topic=CAMERA_TOPIC, reference_image=reference)
    origins = {int(n.parameters["time_origin_unix_ns"]) for n in nodes if "time_origin_unix_ns" in n.parameters}
    if len(origins) != 1:
        raise SystemExit(f"the live nodes were given {len(origins)} lab-clock origins: {sorted(origins)}")
    for n in nodes:
        params = folder / f"{n.spec.name}.params.yaml"
        params.write_text(yaml.safe_dump({"/**": {"ros__parameters": n.parameters}}))
        with (folder / f"{n.spec.name}.log").open("w") as log:
            procs[n.spec.name] = subprocess.Popen(launch_command(n, params), stdout=log,
                                                  stderr=subprocess.STDOUT, env=env)
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


def run_rate(rec: Path, rate_hz: float, folder: Path, env: dict[str, str]) -> tuple[dict, dict, dict[str, float]]:
    """One live run at ``rate_hz``: (camera log, probe log, CPU s per process while streaming)."""
    folder.mkdir(parents=True)
    probe_out, ready, cam_out = folder / "probe.json", folder / "probe.ready", folder / "camera.json"
    with CpuSampler(DOMAIN) as sampler:
        nodes, origin_ns = start_nodes(rec, folder, env)
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
            with (folder / "camera.log").open("w") as log:
                camera = subprocess.run([sys.executable, str(BENCH / "camera_peer.py"), str(rec), str(cam_out),
                                         "--rate-hz", str(rate_hz), "--time-origin-ns", str(origin_ns),
                                         "--ros-args", "-r", "__node:=camera_driver"],
                                        stdout=log, stderr=subprocess.STDOUT, env=env, timeout=300)
            if camera.returncode != 0:
                raise SystemExit(f"camera_peer failed at {rate_hz:g} Hz: {(folder / 'camera.log').read_text()}")
            probe.wait(timeout=180)
            died = {n: p.returncode for n, p in nodes.items() if p.poll() is not None}
        finally:
            stop({**nodes, "probe": probe})
        cam = json.loads(cam_out.read_text())
        seen = json.loads(probe_out.read_text())
        end = max([a for a, *_ in seen["dic"]], default=cam["published_at_s"][-1])
        cpu = sampler.cpu_between(cam["published_at_s"][0], end)
    if died:
        raise SystemExit(f"node(s) exited while streaming at {rate_hz:g} Hz: {died}; logs in {folder}")
    return cam, seen, cpu


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
        "cpu_ms_per_frame_graph": sum(v for k, v in per_frame.items() if k not in ("camera_driver", "bench_probe")),
        "cpu_utilisation_of_cores": sum(cpu.values()) / (window * (os.cpu_count() or 1)),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1500)
    parser.add_argument("--rates", default="250,500,1000", help="camera rates to run (Hz), comma-separated")
    parser.add_argument("--first-image-reference", action="store_true",
                        help="give dic_tracker no reference file: it builds its tracker on the first image (A/B of "
                             "the start-up)")
    args = parser.parse_args()
    rates = [float(r) for r in args.rates.split(",")]
    from vibro_io.rig import load_rig

    rec = cached_recording(args.frames)
    cam = load_rig(rec / "rig.yaml").camera
    truth = json.loads((rec.parent / f"{rec.name}.truth.json").read_text())
    truth_impacts_s = np.array(sorted(i["t"] for i in truth["impacts"]))
    env = dict(os.environ, ROS_DOMAIN_ID=DOMAIN, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    result: dict = {"frames": args.frames, "cores": os.cpu_count(), "goal_rate_hz": GOAL_RATE_HZ,
                    "goal_latency": "one flight + 5 ms", "executor": os.environ.get("VIBRO_EXECUTOR", "events"),
                    "recording": f"vibro synth --no-accel --frames {args.frames} --seed {SEED}"}
    result["tracker_in_process_ms_per_frame"] = tracker_cost_ms(rec)
    one_core = 1e3 / sum(result["tracker_in_process_ms_per_frame"].values())
    result["tracker_one_core_ceiling_frames_per_s"] = one_core
    runs = []
    logs = rec.parent / "runs"  # kept for a look after the run; replaced by the next one
    shutil.rmtree(logs, ignore_errors=True)
    for rate in rates:
        camera_log, seen, cpu = run_rate(rec, rate, logs / f"rate_{rate:g}", env)
        run = summarize(rate, camera_log, seen, cpu, truth_impacts_s, cam.t0_s, cam.fps)
        run["tracked_vs_one_core_ceiling_ratio"] = run["frames_per_s_tracked"] / one_core
        runs.append(run)
    result["runs"] = runs

    c = result["tracker_in_process_ms_per_frame"]
    print(f"baseline, dic_tracker's work in one process: deserialize {c['image_deserialize_ms']:.3f} + DIC "
          f"{c['dic_icgn_ms']:.3f} ms/frame = {one_core:.0f} frames/s on one core")
    for r in runs:
        lag, lat, ex = r["dic_lag_ms"], r["impact_latency_ms"], r["latency_minus_flight_ms"]
        print(f"camera {r['target_rate_hz']:5.0f} Hz: published at {r['publish_rate_hz']:6.1f} Hz, tracked "
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
    out = ROOT / "bench" / "results" / "live.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
