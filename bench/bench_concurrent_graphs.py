"""Several `vibro graph` runs at once on one ROS domain: does every run find its own nodes and finish?

    scripts/py bench/bench_concurrent_graphs.py [--runs 6] [--frames 300] [--fastdds-profile FILE]

Each run is 10 DDS participants (nine nodes and vibro graph's monitor) in its own namespace; N runs started
together put 10 N participants on one domain and host, as several users' runs (or one run beside a lab's other
ROS nodes) do with ROS_DOMAIN_ID unset. Baseline in the same invocation: one run alone on the same recording. Per
run: exit code, wall time, the COR means it printed (the synthetic rig's truth is 0.70) and whether it said that
declared readers never matched. ``--fastdds-profile`` points every run at another Fast DDS profiles file (e.g. one
with only the writer heartbeat, to see Fast DDS's default discovery range; vibro's own profile otherwise). Nothing
is asserted; stdout and bench/results/concurrent_graphs.json (``--out``).
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
VIBRO = [sys.executable, "-m", "vibro_app.cli"]
DOMAIN = os.environ.get("VIBRO_BENCH_DOMAIN", "78")
COR_LINE = re.compile(r"^(top|bottom)\s+\d+\s+([0-9.]+)", re.MULTILINE)


def start(rec: Path, bag: Path, env: dict[str, str]) -> tuple[subprocess.Popen, float]:
    cmd = [*VIBRO, "graph", str(rec), "--bag", str(bag), "--domain-id", DOMAIN, "--timeout-s", "300"]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env), \
        time.monotonic()


def outcome(proc: subprocess.Popen, t0: float) -> dict:
    out, _ = proc.communicate(timeout=400)
    return {"exit_code": proc.returncode, "wall_s": round(time.monotonic() - t0, 1),
            "cor_means": {plate: float(v) for plate, v in COR_LINE.findall(out)},
            "never_matched": "never matched" in out, "tail": out.strip().splitlines()[-1:]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=6)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--fastdds-profile", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "concurrent_graphs.json")
    args = ap.parse_args()
    from vibro_sim.synth import SynthConfig, synthesize

    env = dict(os.environ)
    if args.fastdds_profile is not None:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(args.fastdds_profile.resolve())
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "rec"
        synthesize(rec, SynthConfig(frames=args.frames, seed=11), progress=False)
        alone = outcome(*start(rec, Path(tmp) / "alone", env))
        print(f"one run alone: exit {alone['exit_code']}, {alone['wall_s']} s, COR {alone['cor_means']}")
        started = [start(rec, Path(tmp) / f"bag{i}", env) for i in range(args.runs)]
        runs = [outcome(proc, t0) for proc, t0 in started]
    for i, r in enumerate(runs):
        print(f"run {i + 1} of {args.runs} at once: exit {r['exit_code']}, {r['wall_s']} s, COR {r['cor_means']}"
              + (", declared readers never matched" if r["never_matched"] else ""))
    ok = sum(r["exit_code"] == 0 for r in runs)
    slowest = max(r["wall_s"] for r in runs)
    print(f"{ok} of {args.runs} finished with exit code 0; slowest {slowest} s = {slowest / alone['wall_s']:.1f} x "
          f"one run alone ({args.runs} runs' work on {os.cpu_count()} cores)")
    doc = {"runs": args.runs, "frames": args.frames, "participants_per_domain": 10 * args.runs,
           "fastdds_profile": str(args.fastdds_profile or "vibro's"), "alone": alone, "concurrent": runs,
           "finished_ok": ok, "slowest_over_alone": round(slowest / alone["wall_s"], 2)}
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
