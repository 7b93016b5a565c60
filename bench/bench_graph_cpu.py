"""CPU cost of one whole `vibro graph` run, per process, against `vibro analyze` on the same recording.

    scripts/py bench/bench_graph_cpu.py [--frames 300] [--repeats 2]

The test suite runs `vibro graph` on 300-frame recordings a dozen times, so a run's total CPU (start-up,
discovery, streaming, wind-down of 9 processes) is what sets the suite's time on 2 cores, more than
frames/s. Per run: wall time and each process's CPU seconds from start to exit (bench/proc_cpu.py,
sampled from /proc every 0.1 s; a process's last 0.1 s before it exits may be missed). Baseline in the
same run: `vibro analyze` of the same recording (one process: DIC, identification, simulation,
discrepancy), its CPU from getrusage. Nothing is asserted; stdout and bench/results/graph_cpu.json.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from proc_cpu import CpuSampler  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
VIBRO = [sys.executable, "-m", "vibro_app.cli"]
DOMAIN = os.environ.get("VIBRO_BENCH_DOMAIN", "76")


def children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(cmd: list[str], env: dict[str, str]) -> tuple[float, float, str]:
    """(wall s, CPU s of the command and its waited children, stdout); exits on failure."""
    c0, t0 = children_cpu_s(), time.monotonic()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    wall, cpu = time.monotonic() - t0, children_cpu_s() - c0
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(cmd[2:4])} failed ({res.returncode}):\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return wall, cpu, res.stdout


def graph_run(rec: Path, bag: Path, env: dict[str, str]) -> dict:
    with CpuSampler(DOMAIN) as sampler:
        wall, _, out = run([*VIBRO, "graph", str(rec), "--bag", str(bag), "--domain-id", DOMAIN], env)
    per_process: dict[str, float] = {}
    for _, snap in sampler.samples:
        for name, cpu in snap.items():
            per_process[name] = max(per_process.get(name, 0.0), cpu)
    accounting = next((line for line in out.splitlines() if line.startswith("frames in")), "")
    return {"wall_s": wall, "cpu_s_total": sum(per_process.values()),
            "cpu_s_per_process": dict(sorted(per_process.items(), key=lambda kv: -kv[1])),
            "frame_accounting": accounting}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    env = dict(os.environ, ROS_DOMAIN_ID=DOMAIN, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    with tempfile.TemporaryDirectory(prefix="vibro_bench_graph_cpu_") as tmp:
        rec = Path(tmp) / "rec"
        run([*VIBRO, "synth", "--out", str(rec), "--frames", str(args.frames), "--seed", "11", "--no-progress"], env)
        analyze_wall, analyze_cpu, _ = run([*VIBRO, "analyze", str(rec), "--out", str(Path(tmp) / "an"),
                                            "--no-progress", "--no-report"], env)
        runs = [graph_run(rec, Path(tmp) / f"bag{k}", env) for k in range(args.repeats)]
    result = {"frames": args.frames, "cores": os.cpu_count(),
              "analyze": {"wall_s": analyze_wall, "cpu_s": analyze_cpu}, "graph_runs": runs,
              "graph_vs_analyze_cpu_ratio": [r["cpu_s_total"] / analyze_cpu for r in runs]}
    print(f"vibro analyze, {args.frames} frames: {analyze_wall:.1f} s wall, {analyze_cpu:.1f} s CPU")
    for k, r in enumerate(runs):
        print(f"vibro graph run {k + 1}: {r['wall_s']:.1f} s wall, {r['cpu_s_total']:.1f} s CPU over its processes "
              f"({r['cpu_s_total'] / analyze_cpu:.1f}x analyze); {r['frame_accounting']}")
        for name, cpu in r["cpu_s_per_process"].items():
            print(f"    {name:28s} {cpu:5.2f} s")
    out = ROOT / "bench" / "results" / "graph_cpu.json"
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
