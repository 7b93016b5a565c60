"""Throughput of the node graph vs the offline CLI on one 1500-frame synthetic recording.

    .venv/bin/python bench/bench_graph.py [--frames 1500]

Graph frames/s = frames / (time from frame_source's first frame to its last acknowledged
frame, read from its log stamps); the offline baseline is `vibro analyze` (DIC + identification
+ simulation) on the same recording, timed as a whole. Writes bench/results/graph.json.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VIBRO = [sys.executable, "-m", "vibro_bringup.cli"]


def stamps(log: Path, pattern: str) -> list[float]:
    out = []
    for line in log.read_text().splitlines():
        m = re.match(r"\[\w+\] \[(\d+\.\d+)\] \[\w+\]: (.*)", line)
        if m and re.search(pattern, m.group(2)):
            out.append(float(m.group(1)))
    return out


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=1500)
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "src" / "vibro_sim"))
    from vibro_sim.synth import SynthConfig, synthesize

    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "rec"
        synthesize(rec, SynthConfig(frames=args.frames, seed=21), progress=False)
        env = dict(os.environ, ROS_DOMAIN_ID="77")
        t0 = time.perf_counter()
        graph = subprocess.run([*VIBRO, "graph", str(rec), "--bag", str(Path(tmp) / "bag")], env=env,
                               capture_output=True, text=True)
        graph_wall = time.perf_counter() - t0
        if graph.returncode != 0:
            print(graph.stdout, graph.stderr)
            return 1
        log = Path(tmp) / "bag.logs" / "frame_source.log"
        start, end = stamps(log, r"frames from")[0], stamps(log, r"^done:")[0]
        t0 = time.perf_counter()
        subprocess.run([*VIBRO, "analyze", str(rec), "--out", str(Path(tmp) / "an"), "--no-progress", "--no-report"],
                       check=True, capture_output=True)
        analyze_wall = time.perf_counter() - t0
        line = next(l for l in graph.stdout.splitlines() if l.startswith("frames in"))
    streaming_s = end - start
    result = {
        "frames": args.frames,
        "graph_streaming_s": streaming_s,
        "graph_frames_per_s": args.frames / streaming_s,
        "graph_wall_s": graph_wall,
        "analyze_wall_s": analyze_wall,
        "analyze_frames_per_s": args.frames / analyze_wall,
        "graph_vs_analyze_ratio": (args.frames / streaming_s) / (args.frames / analyze_wall),
        "real_time_goal_frames_per_s": 1000.0,
        "frame_accounting": line,
    }
    for k, v in result.items():
        print(f"{k:28s} {v:.3f}" if isinstance(v, float) else f"{k:28s} {v}")
    out = ROOT / "bench" / "results" / "graph.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
