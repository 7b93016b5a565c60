"""Does watching the graph in Foxglove slow it? `vibro graph` wall time without and with the Foxglove bridge.

    scripts/py bench/bench_foxglove.py [--frames 300] [--repeats 2]

One synthetic recording (``vibro synth``), run through ``vibro graph`` in three modes, interleaved per repeat
so that the machine's load drifts over all modes alike, each on its own private ROS domain:

- ``off``: no bridge;
- ``client``: ``--foxglove`` with a Foxglove-protocol client that subscribes to every channel and reads all;
- ``stalled``: ``--foxglove`` with a client that subscribes to every channel and never reads.

Per run: the graph's own wall time (its summary's ``graph: N s``), the CPU time of vibro graph and all its nodes
(getrusage of the waited-for children: less sensitive to other load on the machine than wall time), frames
tracked and lost, and for the reading client the messages it received per channel and the bridge's own CPU
time (its last ``cpu_s`` on /diagnostics, reported once a second, so up to 1 s short of the end). Nothing is
asserted: stdout and bench/results/foxglove.json. The load average at the start and end of each run is recorded,
since a loaded machine dominates the spread.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import resource
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from foxglove_client import capture, stalled_client  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_graph(rec: Path, out: Path, mode: str, domain: int) -> dict:
    port = _free_port()
    cmd = [sys.executable, "-m", "vibro_app.cli", "graph", str(rec), "--bag", str(out / f"bag_{mode}")]
    if mode != "off":
        cmd += ["--foxglove-port", str(port), "--foxglove-host", "127.0.0.1"]
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    load0 = os.getloadavg()[0]
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    received = {}
    bridge_cpu_s = None
    if mode == "client":
        cap = asyncio.run(capture(f"ws://127.0.0.1:{port}", connect_timeout_s=60,
                                  stop=lambda: proc.poll() is not None, timeout_s=300))
        for m in cap.messages:
            received[m.topic] = received.get(m.topic, 0) + 1
        bridge = [cap.decode(m) for m in cap.on("/diagnostics")]
        bridge = [d["values"]["cpu_s"] for d in bridge if d["node"] == "foxglove_bridge" and "cpu_s" in d["values"]]
        bridge_cpu_s = bridge[-1] if bridge else None
    elif mode == "stalled":
        async def stall_until_done():
            task = asyncio.ensure_future(stalled_client(f"ws://127.0.0.1:{port}", 300))
            while proc.poll() is None:
                await asyncio.sleep(0.2)
            task.cancel()

        asyncio.run(stall_until_done())
    stdout, stderr = proc.communicate(timeout=300)
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)  # vibro graph and every node it started and waited for
    cpu_s = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    graph_s = float(re.search(r"graph: ([\d.]+) s", stdout).group(1))
    frames = re.search(r"frames in (\d+) / tracked (\d+) / lost (\d+)", stdout)
    return {"mode": mode, "exit_code": proc.returncode, "graph_s": graph_s, "cpu_s": round(cpu_s, 2),
            "bridge_cpu_s_last_report": bridge_cpu_s,
            "frames_in": int(frames.group(1)), "tracked": int(frames.group(2)), "lost": int(frames.group(3)),
            "received": received, "load_start": round(load0, 2), "load_end": round(os.getloadavg()[0], 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--domain", type=int, default=150, help="first ROS_DOMAIN_ID used (one per run)")
    args = ap.parse_args()
    runs = []
    with tempfile.TemporaryDirectory(prefix="vibro-bench-foxglove-") as tmp:
        tmp = Path(tmp)
        from vibro_sim.synth import SynthConfig, synthesize

        synthesize(tmp / "rec", SynthConfig(frames=args.frames, seed=5), progress=False)
        domain = args.domain
        for repeat in range(args.repeats):
            for mode in ("off", "client", "stalled"):
                out = tmp / f"r{repeat}_{mode}"
                out.mkdir()
                run = run_graph(tmp / "rec", out, mode, domain)
                domain += 1
                runs.append(run)
                print(json.dumps(run), flush=True)
    summary = {}
    for mode in ("off", "client", "stalled"):
        times = [r["graph_s"] for r in runs if r["mode"] == mode]
        cpu = [r["cpu_s"] for r in runs if r["mode"] == mode]
        summary[mode] = {"graph_s": times, "mean_s": round(sum(times) / len(times), 2), "cpu_s": cpu,
                         "mean_cpu_s": round(sum(cpu) / len(cpu), 2)}
    doc = {"frames": args.frames, "cpus": os.cpu_count(), "runs": runs, "summary": summary}
    target = REPO / "bench" / "results" / "foxglove.json"
    target.write_text(json.dumps(doc, indent=2) + "\n")
    print(json.dumps(summary))
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
