"""Benchmark of vibro's Dask paths: speed-up against workers of a campaign and of chunked DIC.

Run: scripts/py bench/bench_campaign.py [--workers 1,2] [--runs 6] [--frames 300] [--long-frames 1500]
On a bigger machine (no ROS needed): --workers 1,2,4,8,16 --runs 32.
Prints tables and writes bench/results/campaign.json. Everything is measured in this run, each worker count
against the 1-worker run of the same kind in the same run:
- campaign: ``run_campaign`` of RUNS synthetic recordings of FRAMES frames (two excitation groups) on a
  LocalCluster of W workers, fresh output each time: wall, cluster start, the tasks' wall, the sum and max of
  the per-task times (each task = one whole ``vibro analyze``) and the busy fraction sum / (W x tasks wall);
- chunked DIC of one LONG-FRAMES recording: one process (no Dask) vs chunks on W workers (byte-identical
  rows checked), per-chunk times from Dask's task stream, cluster start apart;
- ``analyze_recording`` of the long recording with ``workers=W``: DIC in chunks, identification and the rest
  serial; the serial rest measured directly as the same analysis given the track (no DIC).
BLAS/OpenMP threads are 1 (Dask's nanny does that for its workers) and OpenCV's threads 1 in every process.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "bench" / "results" / "campaign.json"
VIBRO = str(REPO / "vibro")


def _one_cv_thread() -> None:
    import cv2

    cv2.setNumThreads(1)


def synthesize(root: Path, runs: int, frames: int, long_frames: int, parallel: int) -> tuple[Path, Path]:
    """RUNS recordings in root/sweep (half at 27 m/s^2, half at 30 m/s^2) and root/long; a few synths at once."""
    jobs = []
    for i in range(runs):
        accel = "27" if i % 2 == 0 else "30"
        jobs.append([VIBRO, "synth", "--out", str(root / "sweep" / f"run{i:02d}"), "--frames", str(frames),
                     "--seed", str(100 + i), "--accel-mps2", accel, "--cor-scatter", "0.01", "--no-progress"])
    jobs.append([VIBRO, "synth", "--out", str(root / "long"), "--frames", str(long_frames), "--seed", "7",
                 "--no-progress"])
    running: list[subprocess.Popen] = []
    for cmd in jobs:
        while len(running) >= parallel:
            running.pop(0).wait()
        running.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL))
    for p in running:
        p.wait()
        if p.returncode:
            sys.exit("bench_campaign: vibro synth failed")
    return root / "sweep", root / "long"


def bench_campaign(sweep: Path, tmp: Path, workers: int) -> dict:
    from vibro_app.campaign.engine import run_campaign

    out = tmp / f"campaign_w{workers}"
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    doc = run_campaign(sweep, out, workers=workers)
    wall = time.perf_counter() - t0
    tasks = [r["task_s"] for r in doc["runs"] if r.get("task_s")]
    timing = doc["timing"]
    return {"workers": workers, "wall_s": wall, "cluster_start_s": timing["cluster_start_s"],
            "tasks_wall_s": timing["tasks_wall_s"], "task_s_sum": sum(tasks), "task_s_max": max(tasks),
            "task_s_mean": sum(tasks) / len(tasks), "n_tasks": len(tasks),
            "report_s": wall - timing["cluster_start_s"] - timing["tasks_wall_s"],
            "busy_fraction": sum(tasks) / (workers * timing["tasks_wall_s"]),
            "n_failed": doc["summary"]["n_failed"]}


def bench_chunked(long_rec: Path, tmp: Path, workers_list: list[int]) -> tuple[dict, list[dict]]:
    from distributed import get_task_stream

    from vibro_dic.chunked import track_recording_chunked
    from vibro_dic.cluster import dask_client
    from vibro_dic.tracker import track_recording
    from vibro_io.dictrack import write_dic_csv
    from vibro_io.recording import open_recording

    _one_cv_thread()
    rec = open_recording(long_rec)
    t0 = time.perf_counter()
    write_dic_csv(tmp / "serial.csv", track_recording(rec))
    serial = {"workers": 0, "label": "one process, no Dask", "wall_s": time.perf_counter() - t0,
              "frames": len(rec.frames)}
    reference = (tmp / "serial.csv").read_bytes()
    rows = []
    for w in workers_list:
        t0 = time.perf_counter()
        with dask_client(w) as client:
            start = time.perf_counter() - t0
            client.run(_one_cv_thread)
            t1 = time.perf_counter()
            with get_task_stream(client) as stream:
                write_dic_csv(tmp / f"chunked_w{w}.csv", track_recording_chunked(rec, client))
            wall = time.perf_counter() - t1
        chunks = [sum(s["stop"] - s["start"] for s in t["startstops"] if s["action"] == "compute")
                  for t in stream.data if str(t.get("key", "")).startswith("track_chunk")]
        rows.append({"workers": w, "cluster_start_s": start, "track_wall_s": wall, "n_chunks": len(chunks),
                     "chunk_s_sum": sum(chunks), "chunk_s_max": max(chunks) if chunks else None,
                     "busy_fraction": sum(chunks) / (w * wall) if chunks else None,
                     "identical_to_one_process": (tmp / f"chunked_w{w}.csv").read_bytes() == reference})
    return serial, rows


def bench_analyze(long_rec: Path, tmp: Path, workers: int, track_csv: Path) -> dict:
    """``analyze_recording`` with DIC on ``workers`` (1: in this process), and the serial rest measured
    directly: the same analysis given the track (``track_csv``: no DIC)."""
    from vibro_app.analyze import DicPlan, analyze_recording

    t0 = time.perf_counter()
    analyze_recording(long_rec, tmp / f"analyze_w{workers}", progress=False,
                      dic=DicPlan(workers=workers if workers > 1 else None))
    wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    analyze_recording(long_rec, tmp / f"analyze_rest_w{workers}", progress=False, track_csv=track_csv)
    rest = time.perf_counter() - t0
    return {"workers": workers, "wall_s": wall, "serial_rest_s": rest, "dic_and_overhead_s": wall - rest}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", default="1,2", help="comma-separated worker counts (default 1,2)")
    ap.add_argument("--runs", type=int, default=6, help="recordings in the campaign (default 6)")
    ap.add_argument("--frames", type=int, default=300, help="frames per campaign recording (default 300)")
    ap.add_argument("--long-frames", type=int, default=1500, help="frames of the long recording (default 1500)")
    ap.add_argument("--keep", help="keep the recordings and outputs in this folder")
    ap.add_argument("--out", default=str(OUT), help=f"JSON results (default {OUT.relative_to(REPO)})")
    args = ap.parse_args()
    workers_list = sorted({int(w) for w in args.workers.split(",")})
    if workers_list[0] != 1:
        workers_list.insert(0, 1)  # the baseline of every speed-up
    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="vibro-bench-campaign-"))
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        t0 = time.perf_counter()
        sweep, long_rec = synthesize(tmp, args.runs, args.frames, args.long_frames, os.cpu_count() or 1)
        print(f"synthesized {args.runs} x {args.frames} + 1 x {args.long_frames} frames in "
              f"{time.perf_counter() - t0:.0f} s (not measured)")
        campaign = [bench_campaign(sweep, tmp, w) for w in workers_list]
        base = campaign[0]
        for c in campaign:
            c["speedup"] = base["wall_s"] / c["wall_s"]
            c["speedup_tasks_only"] = base["tasks_wall_s"] / c["tasks_wall_s"]
        serial, chunked = bench_chunked(long_rec, tmp, workers_list)
        for c in chunked:
            c["speedup_vs_one_worker"] = chunked[0]["track_wall_s"] / c["track_wall_s"]
            c["speedup_vs_one_process"] = serial["wall_s"] / c["track_wall_s"]
        analyze = [bench_analyze(long_rec, tmp, w, tmp / "serial.csv") for w in workers_list]
        for a in analyze:
            a["speedup"] = analyze[0]["wall_s"] / a["wall_s"]
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)

    print(f"\ncampaign of {args.runs} x {args.frames}-frame recordings (one task = one vibro analyze)")
    print(f"{'W':>3} {'wall s':>8} {'speedup':>8} {'tasks-only':>10} {'start s':>8} {'tasks s':>8} {'sum task':>9} "
          f"{'max task':>9} {'busy':>6} {'report s':>9}")
    for c in campaign:
        print(f"{c['workers']:>3} {c['wall_s']:8.1f} {c['speedup']:8.2f} {c['speedup_tasks_only']:10.2f} "
              f"{c['cluster_start_s']:8.1f} {c['tasks_wall_s']:8.1f} {c['task_s_sum']:9.1f} {c['task_s_max']:9.1f} "
              f"{c['busy_fraction']:6.2f} {c['report_s']:9.1f}")
    print(f"\nchunked DIC of {serial['frames']} frames: one process {serial['wall_s']:.1f} s")
    print(f"{'W':>3} {'track s':>8} {'vs W=1':>7} {'vs 1 proc':>9} {'start s':>8} {'chunks':>6} {'sum chunk':>9} "
          f"{'busy':>6} identical")
    for c in chunked:
        print(f"{c['workers']:>3} {c['track_wall_s']:8.1f} {c['speedup_vs_one_worker']:7.2f} "
              f"{c['speedup_vs_one_process']:9.2f} {c['cluster_start_s']:8.1f} {c['n_chunks']:>6} "
              f"{c['chunk_s_sum']:9.1f} {c['busy_fraction']:6.2f} {c['identical_to_one_process']}")
    print(f"\nanalyze of the {serial['frames']}-frame recording, --workers W (DIC in chunks, the rest serial)")
    print(f"{'W':>3} {'wall s':>8} {'speedup':>8} {'DIC+cluster s':>13} {'serial rest s':>13}")
    for a in analyze:
        print(f"{a['workers']:>3} {a['wall_s']:8.1f} {a['speedup']:8.2f} {a['dic_and_overhead_s']:13.1f} "
              f"{a['serial_rest_s']:13.1f}")

    result = {
        "description": "Speed-up against Dask workers: a campaign (one task per recording) and chunked DIC of "
                       "one long recording; every ratio against the 1-worker run of the same kind in this run.",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform(),
                    "note": "cores may be shared with other work: compare ratios of one run, not across runs"},
        "config": {"workers": workers_list, "runs": args.runs, "frames": args.frames,
                   "long_frames": args.long_frames},
        "campaign": campaign,
        "chunked_dic": {"one_process": serial, "workers": chunked},
        "analyze_long": analyze,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"\nwrote {out}")
    return 0 if all(c["identical_to_one_process"] for c in chunked) and not any(c["n_failed"] for c in campaign) \
        else 1


if __name__ == "__main__":
    sys.exit(main())
