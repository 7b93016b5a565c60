"""Do the published COR sigmas hold the errors? 2-sigma coverage on rendered recordings (issue 39).

For each case (the baseline, and physics the baseline leaves out: drag laws, harmonics, two effects at once, a
plate that steps, a plate that creeps, a position force, a drifting COR) and seed: ``vibro synth`` renders a
recording (frames, DIC noise as the camera gives it, not white noise), ``vibro analyze --no-report`` measures it,
and every published
impact's ``cor`` is matched to the truth file's nearest impact in time. Per recording: the share of impacts
with |cor - truth| < 2 cor_std (the coverage), the median |error| and the median sigma (how much larger the
sigma is than needed), and the COR method the analysis used.

Run: scripts/py bench/bench_coverage.py [--cases all|name,...] [--seeds 1,2] [--frames 1500]
     [--dir /tmp/vibro_coverage] [--reuse] [--json PATH] -> table + bench/results/coverage.json
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
VIBRO = [sys.executable, "-m", "vibro_app.cli"]
RESULTS = ROOT / "bench" / "results" / "coverage.json"
CASES: dict[str, list[str]] = {
    "control": [],
    "quadratic_drag": ["--effect", "quadratic_drag", "--param", "coefficient_ns2_per_m2=5e-4"],
    "viscous_drag": ["--effect", "viscous_drag"],
    "coulomb": ["--effect", "coulomb_friction"],
    "h3": ["--effect", "structure_harmonics", "--param", "h2_ratio=0", "--param", "h3_ratio=0.02"],
    "two_effects": ["--effect", "quadratic_drag", "--param", "coefficient_ns2_per_m2=5e-4",
                    "--effect", "structure_harmonics"],
    "plate_step": ["--effect", "plate_step"],
    "plate_creep": ["--effect", "plate_creep"],
    "creep_and_drag": ["--effect", "plate_creep", "--effect", "quadratic_drag",
                       "--param", "coefficient_ns2_per_m2=5e-4"],
    "spin": ["--spin-sigma-rad-s", "0.3"],
    "horizontal": ["--axis-tilt-deg", "90", "--effect", "coulomb_friction"],
    "lens": ["--lens-k1", "-0.18"],
    "position_force": ["--effect", "position_force"],
    "cor_drift": ["--effect", "cor_drift"],
}


def coverage_of(results: dict, truth: dict) -> dict:
    """Coverage, median |error|, median sigma and methods of ``results``' impacts against ``truth``'s."""
    tt = np.array([i["t"] for i in truth["impacts"]])
    te = np.array([i["cor"] for i in truth["impacts"]])
    errs, sds, methods = [], [], set()
    for imp in results.get("impacts", []):
        if imp.get("cor") is None or imp.get("cor_std") is None:
            continue
        k = int(np.argmin(np.abs(tt - imp["t"])))
        errs.append(imp["cor"] - te[k])
        sds.append(imp["cor_std"])
        methods.add(imp.get("cor_method", "paper"))
    e, s = np.abs(np.array(errs)), np.array(sds)
    if e.size == 0:
        return {"impacts": 0}
    return {"impacts": int(e.size), "coverage_2sigma": float(np.mean(e < 2 * s)),
            "median_abs_error": float(np.median(e)), "median_sigma": float(np.median(s)),
            "z_mean": float(np.mean(np.array(errs) / s)), "methods": sorted(methods),
            "findings": [f.get("effect") for f in (results.get("discrepancy") or {}).get("findings", [])]}


def one(case: str, seed: int, frames: int, work: Path, reuse: bool = False) -> dict:
    """Synthesize (``reuse``: unless made before), analyze and score one recording."""
    rec, out = work / f"{case}_{seed}", work / f"{case}_{seed}_out"
    truth_path = Path(str(rec) + ".truth.json")
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    if not (reuse and truth_path.is_file() and (rec / "rig.yaml").is_file()):
        shutil.rmtree(rec, ignore_errors=True)
        truth_path.unlink(missing_ok=True)
        _synth(case, seed, frames, rec)
    t1 = time.perf_counter()
    ran = subprocess.run([*VIBRO, "analyze", str(rec), "--out", str(out), "--no-report", "--no-progress"],
                         capture_output=True, text=True)
    t2 = time.perf_counter()
    row = {"case": case, "seed": seed, "frames": frames, "analyze_rc": ran.returncode,
           "synth_s": round(t1 - t0, 1), "analyze_s": round(t2 - t1, 1)}
    if ran.returncode not in (0,):
        row["error"] = (ran.stderr or ran.stdout).strip().splitlines()[-1:]
        return row
    truth = json.loads(truth_path.read_text())
    row.update(coverage_of(json.loads((out / "results.json").read_text()), truth))
    return row


def _synth(case: str, seed: int, frames: int, rec: Path) -> None:
    made = subprocess.run([*VIBRO, "synth", "--out", str(rec), "--seed", str(seed), "--frames", str(frames),
                           "--no-accel", "--no-progress", *CASES[case]], capture_output=True, text=True)
    if made.returncode != 0:
        raise SystemExit(f"vibro synth {case} seed {seed}: {made.stderr.strip()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="all")
    ap.add_argument("--seeds", default="1,2")
    ap.add_argument("--frames", type=int, default=1500)
    ap.add_argument("--dir", default="/tmp/vibro_coverage")
    ap.add_argument("--reuse", action="store_true", help="analyze recordings made by an earlier run again")
    ap.add_argument("--json", default=str(RESULTS), help="where the rows go (default bench/results/coverage.json)")
    args = ap.parse_args()
    cases = list(CASES) if args.cases == "all" else args.cases.split(",")
    work = Path(args.dir)
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for case in cases:
        for seed in (int(s) for s in args.seeds.split(",")):
            row = one(case, seed, args.frames, work, args.reuse)
            rows.append(row)
            cov = row.get("coverage_2sigma")
            print(f"{case:15s} seed {seed}: " + (f"coverage {cov:.3f} of {row['impacts']}, median |err| "
                  f"{row['median_abs_error']:.1e}, median sigma {row['median_sigma']:.1e}, z mean "
                  f"{row['z_mean']:+.2f}, {'+'.join(row['methods'])}" if cov is not None else
                  f"no coverage ({row.get('error') or row.get('impacts')})"), flush=True)
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
