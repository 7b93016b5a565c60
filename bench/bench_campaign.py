"""Benchmark of vibro's Dask paths: speed-up against workers of a campaign and of chunked DIC, and a model of a
campaign's wall time on W workers.

Run: scripts/py bench/bench_campaign.py [--workers 1,2] [--runs 6] [--frames 300] [--long-frames 1500]
         [--parts campaign,chunked,analyze] [--compare-engine OLD_engine.py] [--model 4,8,16]
On a bigger machine (no ROS needed): --workers 1,2,4,8,16 --runs 32 --frames 1000.
Prints tables and writes bench/results/campaign.json. Everything is measured in this run, each worker count
against the 1-worker run of the same kind in the same run:
- campaign: ``run_campaign`` of RUNS synthetic recordings of FRAMES frames (two excitation groups; ``--frames
  150,450`` cycles lengths over the runs) on a LocalCluster of W workers, fresh output each time: wall, the
  serial parts before the tasks (run list and fingerprints, the wait for the cluster), the tasks' wall, the sum
  and max of the per-task times (each task = one whole ``vibro analyze``), the busy fraction
  sum / (W x tasks wall) and the serial tail after the last task; the load average before and after.
  ``--compare-engine FILE``: the same campaign also through ``run_campaign`` of another engine.py (e.g. a copy
  of an earlier version), interleaved with this one at each W, so both see the same machine;
- ``--model W1,W2,...``: the campaign's predicted wall time and speed-up on W workers from this run's measured
  task times (see :func:`model_campaign`), for this engine and, with ``--compare-engine``, the other one;
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
import heapq  # noqa: E402
import importlib.util  # noqa: E402
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


def synthesize(root: Path, runs: int, frames: list[int], long_frames: int | None, parallel: int) -> tuple[Path, Path]:
    """RUNS recordings in root/sweep (half at 27 m/s^2, half at 30 m/s^2; lengths ``frames`` cycled over the runs)
    and root/long (unless ``long_frames`` is None); a few synths at once; recordings already there are kept."""
    jobs = []
    for i in range(runs):
        accel = "27" if i % 2 == 0 else "30"
        jobs.append([VIBRO, "synth", "--out", str(root / "sweep" / f"run{i:02d}"), "--frames",
                     str(frames[i % len(frames)]), "--seed", str(100 + i), "--accel-mps2", accel, "--cor-scatter",
                     "0.01", "--no-progress"])
    if long_frames is not None:
        jobs.append([VIBRO, "synth", "--out", str(root / "long"), "--frames", str(long_frames), "--seed", "7",
                     "--no-progress"])
    jobs = [cmd for cmd in jobs if not (Path(cmd[3]) / "rig.yaml").is_file()]
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


def load_engine(path: str | None):
    """``run_campaign`` of this checkout's engine (None) or of the engine.py file at ``path``."""
    if path is None:
        from vibro_app.campaign.engine import run_campaign

        return run_campaign
    spec = importlib.util.spec_from_file_location("vibro_bench_other_engine", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.run_campaign


def bench_campaign(run_campaign, sweep: Path, tmp: Path, workers: int, label: str) -> dict:
    """One campaign on ``workers`` through ``run_campaign``: times, the per-task times by run, the load average."""
    out = tmp / f"campaign_{label}_w{workers}"
    shutil.rmtree(out, ignore_errors=True)
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    doc = run_campaign(sweep, out, workers=workers)
    wall = time.perf_counter() - t0
    task_s = {r["name"]: r["task_s"] for r in doc["runs"] if r.get("task_s")}
    tasks = list(task_s.values())
    timing = doc["timing"]
    # the serial part before the first task: run list and fingerprints, then the wait for the cluster (this
    # engine: started in the background meanwhile; an earlier one: started after, its start all serial)
    if "cluster_wait_s" in timing:
        before_tasks = timing["prepare_s"] + timing["cluster_wait_s"]
    else:
        before_tasks = timing["cluster_start_s"]  # its run list and fingerprints (~0.1 s) fall in the tail here
    schedule = timing.get("schedule")
    return {"engine": label, "workers": workers, "wall_s": wall, "cluster_start_s": timing["cluster_start_s"],
            "cluster_wait_s": timing.get("cluster_wait_s"), "before_tasks_s": before_tasks,
            "tasks_wall_s": timing["tasks_wall_s"],
            "tail_s": wall - before_tasks - timing["tasks_wall_s"], "after_tasks": timing.get("after_tasks"),
            "task_s_sum": sum(tasks), "task_s_max": max(tasks), "task_s_mean": sum(tasks) / len(tasks),
            "n_tasks": len(tasks), "busy_fraction": sum(tasks) / (workers * timing["tasks_wall_s"]),
            "task_s": task_s, "submitted": [r["name"] for r in schedule["runs"]] if schedule else sorted(task_s),
            "cost_bytes": {r["name"]: r["cost_bytes"] for r in schedule["runs"]} if schedule else None,
            "load_avg_before": load_before, "load_avg_after": os.getloadavg(),
            "n_failed": doc["summary"]["n_failed"]}


# --- model of a campaign's wall time on W workers --------------------------------------------------------------

#: the 16-core measurement of issue 41 (an earlier engine: FIFO, cluster started after the fingerprints, report
#: and close after the last task): 32 runs of 1000 frames
ISSUE_16CORE = {"workers": 16, "runs": 32, "tasks_sum_1_worker_s": 204.8, "wall_1_worker_s": 212.0,
                "tasks_wall_s": 20.1, "cluster_start_s": 2.7, "wall_s": 27.7}


def list_schedule(durations: list[float], workers: int, first_extra: float = 0.0) -> float:
    """Makespan of list scheduling: tasks taken in the given order, each by the worker that frees first;
    ``first_extra`` (s) added to each worker's first task (its imports and kernel loads)."""
    free = [(0.0, w, True) for w in range(workers)]
    heapq.heapify(free)
    end = 0.0
    for d in durations:
        t, w, first = heapq.heappop(free)
        t += d + (first_extra if first else 0.0)
        end = max(end, t)
        heapq.heappush(free, (t, w, False))
    return end


def worker_imports_s() -> float:
    """Seconds a fresh worker process spends on its first task's imports and the numba kernels' load (measured
    here in a child process: vibro_app.analyze, matplotlib, scipy, vibro_dic.tracker.compile_kernels)."""
    code = ("import time; t = time.perf_counter(); import vibro_app.analyze, matplotlib; matplotlib.use('Agg'); "
            "import matplotlib.pyplot, scipy.stats; from vibro_dic.tracker import compile_kernels; "
            "compile_kernels(); print(time.perf_counter() - t)")
    out = subprocess.run([str(REPO / "scripts" / "py"), "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])


def _interp(points: dict[int, float], w: int) -> float:
    """Piecewise-linear in W through ``points`` {W: value}, flat beyond the ends."""
    xs = sorted(points)
    if w <= xs[0]:
        return points[xs[0]]
    for a, b in zip(xs, xs[1:]):
        if w <= b:
            return points[a] + (points[b] - points[a]) * (w - a) / (b - a)
    return points[xs[-1]]


def model_campaign(after: dict[int, dict], before: dict[int, dict] | None, workers: list[int], imports_s: float,
                   runs: int = ISSUE_16CORE["runs"]) -> dict:
    """T(W) = unhidden cluster start + makespan + serial tail after the last task, for a campaign of ``runs`` runs
    like the measured ones on the 16-core machine of :data:`ISSUE_16CORE`, for this engine (``after``: its
    measured campaigns by W) and an earlier one (``before``, measured with ``--compare-engine``):

    - task times: this engine's 1-worker per-task times, cycled to ``runs`` tasks (and their cost estimates, the
      recordings' bytes, with them) and scaled to the 16-core machine's mean task (204.8 s / 32); the task that
      ran first here loses ``imports_s`` (a fresh worker's imports and kernel loads, measured apart; not scaled:
      they do not grow with the frames, and that machine's core speed is taken as this one's), which every
      worker's first task gets back;
    - order: this engine longest first by its estimate (ties by name), the earlier one FIFO by name; both as
      list scheduling (each worker takes the next task when it frees). The earlier engine ran with Dask's
      default worker-saturation, which binds a second task to each single-thread worker, so its model is
      optimistic;
    - contention: every task x s(W) on W workers, s(W) = 1 + (s16 - 1)(W - 1)/15, s16 fitted so that the
      earlier engine's model gives the 16-core machine's tasks wall (so that model reproduces 27.7 s at 16),
      at least 1 (a fit below 1 says the tasks measured here are more uneven than that machine's);
    - cluster start: this engine's, measured here at W = 1, and 2.7 s at 16 (issue), linear between; this engine
      hides what overlapped its run list and fingerprints (start - wait, measured here at W = 1), the earlier
      one nothing;
    - tail: this engine's measured here (at W, else at the largest W measured); the earlier one's measured here
      at W = 1 (and 2) and the 16-core machine's 4.9 s at 16, linear between.

    ``check``: the same list scheduling on this machine (the measured runs, not cycled; s(2) = mean task time at
    2 workers / at 1 of the same engine) against the tasks wall measured at W = 2.
    """
    base = after[1]
    names = sorted(base["task_s"])
    first = base["submitted"][0]
    per_task = {n: base["task_s"][n] - (imports_s if n == first else 0.0) for n in names}
    cost = base["cost_bytes"] or {n: 0 for n in names}

    def orders(cycle: list[str]) -> tuple[list[float], list[float]]:
        tiled = list(enumerate(cycle))
        lpt = [per_task[n] for _, n in sorted(tiled, key=lambda x: (-cost[x[1]], x[1], x[0]))]
        return lpt, [per_task[n] for n in cycle]

    lpt, fifo = orders([names[i % len(names)] for i in range(runs)])
    scale16 = (ISSUE_16CORE["tasks_sum_1_worker_s"] / ISSUE_16CORE["runs"]) / (sum(fifo) / len(fifo))
    lo, hi = 0.5, 5.0
    for _ in range(60):  # s16: the earlier engine's model on the 16-core machine = its measured tasks wall
        mid = (lo + hi) / 2
        m = list_schedule([t * scale16 * mid for t in fifo], 16, imports_s * mid)
        lo, hi = (mid, hi) if m < ISSUE_16CORE["tasks_wall_s"] else (lo, mid)
    s16_fit = (lo + hi) / 2
    # below 1: the tasks here are more uneven than that machine's (a loaded machine's noise); no speed-up from that
    s16 = max(1.0, s16_fit)
    start_points = {1: base["cluster_start_s"], 16: ISSUE_16CORE["cluster_start_s"]}
    hidden = max(0.0, base["cluster_start_s"] - base["cluster_wait_s"]) if base.get("cluster_wait_s") is not None \
        else 0.0
    tail_before = {w: c["tail_s"] for w, c in (before or {}).items() if w <= 2}
    tail_before[16] = ISSUE_16CORE["wall_s"] - ISSUE_16CORE["cluster_start_s"] - ISSUE_16CORE["tasks_wall_s"]

    def predict(order: list[float], w: int, hidden: float, tail: float) -> dict:
        s = 1.0 + (s16 - 1.0) * (w - 1) / 15
        start = _interp(start_points, w)
        makespan = list_schedule([t * scale16 * s for t in order], w, imports_s * s)
        unhidden = max(0.0, start - hidden)
        return {"workers": w, "s": s, "cluster_start_s": start, "start_unhidden_s": unhidden,
                "makespan_s": makespan, "tail_s": tail, "wall_s": unhidden + makespan + tail}

    out = {"runs": runs, "imports_s": imports_s, "start_hidden_s": hidden, "s16": s16, "s16_fit": s16_fit,
           "cluster_start_points": start_points, "tail_before_points": tail_before, "scale_to_16core": scale16,
           "after": [], "before": [], "check": []}
    for w in sorted({1, *workers}):
        tail_after = after[w]["tail_s"] if w in after else after[max(after)]["tail_s"]
        out["after"].append(predict(lpt, w, hidden, tail_after))
        if before is not None:
            out["before"].append(predict(fifo, w, 0.0, _interp(tail_before, w)))
    for key in ("after", "before"):
        if out[key]:
            one = out[key][0]["wall_s"]
            for p in out[key]:
                p["speedup"] = one / p["wall_s"]
    local_lpt, local_fifo = orders(names)
    for label, measured, order in (("this engine", after, local_lpt), ("compared engine", before, local_fifo)):
        if measured and 2 in measured and 1 in measured:
            s2 = measured[2]["task_s_mean"] / measured[1]["task_s_mean"]
            out["check"].append({"engine": label, "s2": s2, "tasks_wall_measured_s": measured[2]["tasks_wall_s"],
                                 "makespan_model_s": list_schedule([t * s2 for t in order], 2, imports_s * s2)})
    return out


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


def _measure(args, engines: dict, workers_list: list[int], frames: list[int], parts: set[str], tmp: Path):
    """(campaign rows by engine, model or None, one-process DIC, chunked DIC rows, analyze rows)."""
    from vibro_dic.cluster import dask_client

    campaign: dict[str, list[dict]] = {k: [] for k in engines}
    if "campaign" in parts:
        with dask_client(1):  # not timed: the first cluster of a process pays one-time imports, whichever engine
            pass
    serial, chunked, analyze, model = None, [], [], None
    t0 = time.perf_counter()
    long_frames = args.long_frames if parts & {"chunked", "analyze"} else None
    sweep, long_rec = synthesize(tmp, args.runs, frames, long_frames, os.cpu_count() or 1)
    print(f"synthesized {args.runs} x {args.frames} frames" + (f" + 1 x {long_frames}" if long_frames else "")
          + f" in {time.perf_counter() - t0:.0f} s (not measured)")
    if "campaign" in parts:
        for i, w in enumerate(workers_list):
            labels = list(engines) if i % 2 == 0 else list(engines)[::-1]  # interleaved: ABBA over W
            for label in labels:
                campaign[label].append(bench_campaign(engines[label], sweep, tmp, w, label))
        for rows in campaign.values():
            rows.sort(key=lambda c: c["workers"])
            for c in rows:
                c["speedup"] = rows[0]["wall_s"] / c["wall_s"]
                c["speedup_tasks_only"] = rows[0]["tasks_wall_s"] / c["tasks_wall_s"]
        if args.model:
            model = model_campaign({c["workers"]: c for c in campaign["this"]},
                                   {c["workers"]: c for c in campaign["other"]} if "other" in campaign else None,
                                   [int(w) for w in args.model.split(",")], worker_imports_s())
    if "chunked" in parts or "analyze" in parts:
        serial, chunked = bench_chunked(long_rec, tmp, workers_list)
        for c in chunked:
            c["speedup_vs_one_worker"] = chunked[0]["track_wall_s"] / c["track_wall_s"]
            c["speedup_vs_one_process"] = serial["wall_s"] / c["track_wall_s"]
    if "analyze" in parts:
        analyze = [bench_analyze(long_rec, tmp, w, tmp / "serial.csv") for w in workers_list]
        for a in analyze:
            a["speedup"] = analyze[0]["wall_s"] / a["wall_s"]
    return campaign, model, serial, chunked, analyze


def _print_campaign(rows: list[dict], title: str) -> None:
    print(f"\n{title}")
    print(f"{'W':>3} {'wall s':>8} {'speedup':>8} {'tasks-only':>10} {'start s':>8} {'pre-task s':>10} "
          f"{'tasks s':>8} {'sum task':>9} {'max task':>9} {'busy':>6} {'tail s':>7} {'load 1m before/after':>21}")
    for c in rows:
        print(f"{c['workers']:>3} {c['wall_s']:8.1f} {c['speedup']:8.2f} {c['speedup_tasks_only']:10.2f} "
              f"{c['cluster_start_s']:8.2f} {c['before_tasks_s']:10.2f} {c['tasks_wall_s']:8.1f} "
              f"{c['task_s_sum']:9.1f} {c['task_s_max']:9.1f} {c['busy_fraction']:6.2f} {c['tail_s']:7.2f} "
              f"{c['load_avg_before'][0]:10.2f}/{c['load_avg_after'][0]:.2f}")


def _print_model(model: dict, label: str, key: str) -> None:
    print(f"{label}:")
    print(f"{'W':>3} {'s(W)':>6} {'start':>6} {'unhidden':>8} {'makespan':>9} {'tail':>6} {'T(W) s':>8} "
          f"{'speed-up':>8}")
    for p in model[key]:
        print(f"{p['workers']:>3} {p['s']:6.2f} {p['cluster_start_s']:6.2f} {p['start_unhidden_s']:8.2f} "
              f"{p['makespan_s']:9.1f} {p['tail_s']:6.2f} {p['wall_s']:8.1f} {p['speedup']:8.2f}")


def _print_models(model: dict) -> None:
    print(f"\nmodel of a campaign of {model['runs']} runs like these on the 16-core machine (model_campaign): worker "
          f"imports {model['imports_s']:.2f} s, s16 {model['s16']:.2f} (fit {model['s16_fit']:.2f}), "
          f"start hidden {model['start_hidden_s']:.2f} s; "
          f"tasks x{model['scale_to_16core']:.2f} (to the 16-core machine's mean task)")
    _print_model(model, "this engine (longest first, start in the background, rows in the loop, fast close)", "after")
    if model["before"]:
        _print_model(model, "the compared engine (FIFO, start after the fingerprints, report and close after the "
                            "last task)", "before")
    for c in model["check"]:
        print(f"check here, {c['engine']}, W = 2: s(2) {c['s2']:.2f}, tasks wall measured "
              f"{c['tasks_wall_measured_s']:.1f} s, list-scheduling model {c['makespan_model_s']:.1f} s")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", default="1,2", help="comma-separated worker counts (default 1,2)")
    ap.add_argument("--runs", type=int, default=6, help="recordings in the campaign (default 6)")
    ap.add_argument("--frames", default="300",
                    help="frames per campaign recording; a comma list is cycled over the runs (default 300)")
    ap.add_argument("--long-frames", type=int, default=1500, help="frames of the long recording (default 1500)")
    ap.add_argument("--parts", default="campaign,chunked,analyze",
                    help="what to measure: campaign, chunked, analyze (comma list; default all three)")
    ap.add_argument("--compare-engine", metavar="ENGINE_PY",
                    help="also run each campaign through run_campaign of this engine.py (e.g. an earlier version)")
    ap.add_argument("--model", metavar="W1,W2,...",
                    help="predict the campaign's wall time and speed-up on these worker counts from this run's "
                         "measured task times (model_campaign; needs the campaign part)")
    ap.add_argument("--model-from", metavar="RESULTS_JSON",
                    help="only recompute --model from the campaigns measured in an earlier results file of this "
                         "bench (run with --compare-engine for the earlier engine's model); writes nothing")
    ap.add_argument("--keep", help="keep the recordings and outputs in this folder (recordings there are reused)")
    ap.add_argument("--out", default=str(OUT), help=f"JSON results (default {OUT.relative_to(REPO)})")
    args = ap.parse_args()
    if args.model_from:
        earlier = json.loads(Path(args.model_from).read_text())
        other = earlier.get("campaign_compared_engine")
        _print_models(model_campaign({c["workers"]: c for c in earlier["campaign"]},
                                     {c["workers"]: c for c in other} if other else None,
                                     [int(w) for w in (args.model or "4,8,16").split(",")],
                                     earlier["model"]["imports_s"] if earlier.get("model") else worker_imports_s()))
        return 0
    workers_list = sorted({int(w) for w in args.workers.split(",")})
    if workers_list[0] != 1:
        workers_list.insert(0, 1)  # the baseline of every speed-up
    frames = [int(f) for f in args.frames.split(",")]
    parts = set(args.parts.split(","))
    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="vibro-bench-campaign-"))
    tmp.mkdir(parents=True, exist_ok=True)
    engines = {"this": load_engine(None)}
    if args.compare_engine:
        engines["other"] = load_engine(args.compare_engine)
    try:
        campaign, model, serial, chunked, analyze = _measure(args, engines, workers_list, frames, parts, tmp)
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)

    for label, rows in campaign.items():
        if rows:
            name = "this engine" if label == "this" else f"engine {args.compare_engine}"
            _print_campaign(rows, f"campaign of {args.runs} x {args.frames}-frame recordings, {name} "
                                  f"(one task = one vibro analyze)")
    if model is not None:
        _print_models(model)
    if serial is not None:
        print(f"\nchunked DIC of {serial['frames']} frames: one process {serial['wall_s']:.1f} s")
        print(f"{'W':>3} {'track s':>8} {'vs W=1':>7} {'vs 1 proc':>9} {'start s':>8} {'chunks':>6} {'sum chunk':>9} "
              f"{'busy':>6} identical")
        for c in chunked:
            print(f"{c['workers']:>3} {c['track_wall_s']:8.1f} {c['speedup_vs_one_worker']:7.2f} "
                  f"{c['speedup_vs_one_process']:9.2f} {c['cluster_start_s']:8.1f} {c['n_chunks']:>6} "
                  f"{c['chunk_s_sum']:9.1f} {c['busy_fraction']:6.2f} {c['identical_to_one_process']}")
    if analyze:
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
        "config": {"workers": workers_list, "runs": args.runs, "frames": frames, "long_frames": args.long_frames,
                   "parts": sorted(parts), "compare_engine": args.compare_engine, "model": args.model},
        "campaign": campaign["this"],
        "campaign_compared_engine": campaign.get("other"),
        "model": model,
        "chunked_dic": {"one_process": serial, "workers": chunked},
        "analyze_long": analyze,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"\nwrote {out}")
    failed = any(c["n_failed"] for rows in campaign.values() for c in rows)
    return 0 if all(c["identical_to_one_process"] for c in chunked) and not failed else 1


if __name__ == "__main__":
    sys.exit(main())
