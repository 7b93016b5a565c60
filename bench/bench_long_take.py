"""A lab's long take, end to end, scored window by window (issue 38).

For each seed: ``vibro synth --lab-files`` writes a take as a lab records it (an 8-bit Photron MRAW + .cih, an
NI TDMS at 50 kHz, no rig.yaml) with what a lab's long take does: the shaker's amplitude steps by 10 % at the
middle within 0.5 s, the DAQ's clock runs 200 ppm fast and 3 ms late, the ball meets a quadratic drag
(5e-4 N s^2/m^2) and its CORs scatter by 0.015. Then, each a child process timed alone (wall, peak RSS from
``os.wait4``): ``vibro init RUN --ball-diameter-mm 4.77 --gap-mm 16.6`` (the two lengths a lab types) and
``vibro analyze RUN --out OUT`` (with its report). results.json is scored against the truth file: every
impact's COR error, window by window (2 s), for the published ``cor`` and the first pass (``cor_paper``); the
DAQ clock's rate; the drive's step; the findings.

``--creep-um-per-s R`` adds an upper plate that creeps R um/s over the take (``plate_creep``).

Run: scripts/py bench/bench_long_take.py [--frames 20000] [--seeds 5,6,7] [--dir /tmp/vibro_long_take]
     [--creep-um-per-s R] [--json PATH] -> table + bench/results/long_take.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
VIBRO = [sys.executable, "-m", "vibro_app.cli"]
RESULTS = ROOT / "bench" / "results" / "long_take.json"
WINDOW_S = 2.0
TAKE = ["--effect", "drive_change", "--param", "amplitude_step_ratio=0.1", "--param", "amplitude_ramp_s=0.5",
        "--effect", "quadratic_drag", "--param", "coefficient_ns2_per_m2=5e-4", "--daq-clock-ppm", "200",
        "--clock-offset-ms", "3", "--cor-scatter", "0.015"]


def run_child(args: list[str]) -> dict:
    """``vibro ARGS`` as a child: exit code, wall s, its own peak RSS MiB (``os.wait4``), the load before."""
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.Popen([*VIBRO, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
    out = proc.stdout.read().decode(errors="replace")
    err = proc.stderr.read().decode(errors="replace")
    _, status, usage = os.wait4(proc.pid, 0)
    return {"rc": os.waitstatus_to_exitcode(status), "wall_s": time.perf_counter() - t0,
            "peak_mib": usage.ru_maxrss / 1024, "load_before": load, "stdout": out[-4000:], "stderr": err[-2000:]}


def score(results: dict, truth: dict) -> dict:
    """COR errors against the truth, window by window, for ``cor`` and ``cor_paper``; impacts found."""
    truth_t = np.array([i["t"] for i in truth["impacts"]])
    truth_e = np.array([i["cor"] for i in truth["impacts"]])
    rows = [i for i in results["impacts"] if i["cor"] is not None]
    k = np.array([int(np.argmin(np.abs(truth_t - i["t"]))) for i in rows])
    t = np.array([i["t"] for i in rows])
    err = np.array([i["cor"] for i in rows]) - truth_e[k]
    paper = np.array([i["cor_paper"] for i in rows]) - truth_e[k]
    std = np.array([i["cor_std"] for i in rows])
    windows = []
    for lo in np.arange(0.0, float(truth_t.max()) + 1e-9, WINDOW_S):
        sel = (t >= lo) & (t < lo + WINDOW_S)
        if sel.any():
            windows.append({"t_s": [float(lo), float(lo + WINDOW_S)], "n": int(sel.sum()),
                            "max_abs_error": float(np.max(np.abs(err[sel]))),
                            "mean_error": float(np.mean(err[sel])),
                            "first_pass_max_abs_error": float(np.max(np.abs(paper[sel])))})
    return {"impacts_found": len(rows), "impacts_true": int(truth_t.size),
            "max_time_error_ms": float(1e3 * np.max(np.abs(truth_t[k] - t))),
            "mae": float(np.mean(np.abs(err))), "max_abs_error": float(np.max(np.abs(err))),
            "first_pass_mae": float(np.mean(np.abs(paper))),
            "within_2_sigma": float(np.mean(np.abs(err) < 2 * std)), "windows": windows}


def one_seed(seed: int, frames: int, work: Path, extra: list[str] | None = None) -> dict:
    rec, out = work / f"take{seed}", work / f"take{seed}_out"
    for p in (rec, out):
        shutil.rmtree(p, ignore_errors=True)
    Path(f"{rec}.truth.json").unlink(missing_ok=True)   # beside the recording: a second run would refuse it
    row: dict = {"seed": seed, "frames": frames}
    print(f"[seed {seed}] vibro synth --lab-files ({frames} frames)", file=sys.stderr, flush=True)
    row["synth"] = run_child(["synth", "--out", str(rec), "--frames", str(frames), "--seed", str(seed),
                              "--lab-files", "--no-progress", *TAKE, *(extra or [])])
    print(f"[seed {seed}] vibro init", file=sys.stderr, flush=True)
    row["init"] = run_child(["init", str(rec), "--ball-diameter-mm", "4.77", "--gap-mm", "16.6"])
    print(f"[seed {seed}] vibro analyze", file=sys.stderr, flush=True)
    row["analyze"] = run_child(["analyze", str(rec), "--out", str(out), "--no-progress"])
    if row["analyze"]["rc"] != 0:
        return row
    results = json.loads((out / "results.json").read_text())
    truth = json.loads(Path(f"{rec}.truth.json").read_text())
    row["score"] = score(results, truth)
    clock = results["accelerometers"]["clock_offset"]
    row["clock"] = {"rate_ppm": clock.get("rate_ppm"), "rate_std_ppm": clock.get("rate_std_ppm"),
                    "true_rate_ppm": truth.get("daq_clock_ppm")}
    amplitude = (results.get("drive") or {}).get("amplitude") or {}
    row["drive"] = {"stationary": (results.get("drive") or {}).get("stationary"),
                    "change_ratio": amplitude.get("change_ratio"), "t_s": amplitude.get("t_s")}
    row["findings"] = [f["effect"] for f in results["discrepancy"]["findings"]]
    row["plate_motion"] = {p: {k: m.get(k) for k in ("shape", "applied", "rate_um_per_s", "rate_std_um_per_s")}
                           for p, m in (results.get("plate_motion") or {}).items()}
    row["score_by_plate"] = {p: score(dict(results, impacts=[i for i in results["impacts"] if i["plate"] == p]),
                                      truth) for p in ("top", "bottom")}
    shutil.rmtree(rec, ignore_errors=True)  # 1.5 GB of MRAW per 20,000 frames
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--seeds", default="5,6,7")
    ap.add_argument("--dir", default="/tmp/vibro_long_take")
    ap.add_argument("--creep-um-per-s", type=float, default=None, help="an upper plate creeping this fast (um/s)")
    ap.add_argument("--json", default=str(RESULTS), help="where the rows go (default bench/results/long_take.json)")
    args = ap.parse_args()
    work = Path(args.dir)
    work.mkdir(parents=True, exist_ok=True)
    extra = [] if args.creep_um_per_s is None else ["--effect", "plate_creep", "--param",
                                                     f"creep_um_per_s={args.creep_um_per_s}"]
    rows = [one_seed(int(s), args.frames, work, extra) for s in args.seeds.split(",")]
    for r in rows:
        s = r.get("score", {})
        print(f"seed {r['seed']}: init {r['init']['wall_s']:.1f} s {r['init']['peak_mib']:.0f} MiB, analyze "
              f"{r['analyze']['wall_s']:.1f} s {r['analyze']['peak_mib']:.0f} MiB (rc {r['analyze']['rc']}); "
              f"impacts {s.get('impacts_found')}/{s.get('impacts_true')}; COR MAE {s.get('mae', float('nan')):.2g} "
              f"max {s.get('max_abs_error', float('nan')):.2g} (first pass MAE "
              f"{s.get('first_pass_mae', float('nan')):.2g}); worst 2 s window "
              f"{max((w['max_abs_error'] for w in s.get('windows', [])), default=float('nan')):.2g}; "
              f"rate {r.get('clock', {}).get('rate_ppm')} ppm; drive {r.get('drive')}; findings {r.get('findings')}")
        for plate, sp in (r.get("score_by_plate") or {}).items():
            print(f"  {plate}: within 2 sigma {sp.get('within_2_sigma', float('nan')):.3f}, MAE "
                  f"{sp.get('mae', float('nan')):.2g}, worst window "
                  f"{max((w['max_abs_error'] for w in sp.get('windows', [])), default=float('nan')):.2g}; "
                  f"plate {(r.get('plate_motion') or {}).get(plate)}")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"command": " ".join(sys.argv), "take": TAKE + extra, "runs": rows}, indent=1) + "\n")
    print(f"wrote {out}")
    return 0 if all(r["analyze"]["rc"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
