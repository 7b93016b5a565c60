"""Discrepancy analysis, blind, on concealed effects: the full ``vibro prove`` run, vibro vs PySINDy.

Recordings of 1500 frames (1.5 s at 1000 fps) rendered by the synthetic rig with one effect (a quarter
of the effect cases get a second, compatible one) or none (controls), drawn from the documented ranges
of vibro_eval/prove.py; ``vibro analyze`` (DIC -> identification -> discrepancy) runs on each
recording directory alone; the truth is read only to score. The baseline measured in the same run is
PySINDy given the same measured data (per-flight tracks, per-impact velocities, the structure track)
with a library of the same terms, scored the same way, and the baseline model's D.

Run: scripts/py bench/bench_discrepancy.py [--cases 40] [--frames 1500] [--seed 2026]
     -> table + bench/results/discrepancy.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from side_by_side import print_side_by_side  # noqa: E402

from vibro_eval.prove import GOALS, ProofCases, format_summary, prove  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=40)
    ap.add_argument("--frames", type=int, default=1500)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--pairs", type=float, default=0.25)
    ap.add_argument("--out", default="/tmp/vibro_bench_discrepancy")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    res = prove(ProofCases(cases=args.cases, seed=args.seed, frames=args.frames, pairs=args.pairs), args.out,
                sindy=True, progress=sys.stderr.isatty())
    wall = time.perf_counter() - t0
    v, s = res["vibro"], res.get("sindy")
    print(format_summary(v, f"vibro ({args.cases} cases, {args.frames} frames)"))
    if s:
        print(format_summary(s, f"PySINDy {res['settings']['pysindy']} on the same data"))
    rows = res["rows"]
    d_base = [r["deviation"]["baseline"] for r in rows if r.get("deviation") and r["family"] != "none"]
    d_fin = [r["deviation"]["final"] for r in rows if r.get("deviation") and r["family"] != "none"]
    d_true = [r["deviation"]["true_model"] for r in rows if r.get("deviation") and r["family"] != "none"]
    d_sin = [r["sindy"]["deviation"]["final"] for r in rows if r.get("sindy", {}).get("deviation")
             and r["family"] != "none"]
    table = {
        "effects identified (%)": (v["identified_pct"], s and s["identified_pct"]),
        "spurious findings (effect cases)": (v["spurious_findings_on_effect_cases"],
                                             s and s["spurious_findings_on_effect_cases"]),
        "controls without finding": (f"{v['controls_without_finding']}/{v['controls']}",
                                     s and f"{s['controls_without_finding']}/{s['controls']}"),
        "main parameter error, median (%)": (v["parameter_error_median_pct"], s and s["parameter_error_median_pct"]),
        "main parameter error, max (%)": (v["parameter_error_max_pct"], s and s["parameter_error_max_pct"]),
        "D after / D true, median": (v["d_final_over_true_median"], s and s["d_final_over_true_median"]),
        "D after / D true, max": (v["d_final_over_true_max"], s and s["d_final_over_true_max"]),
        "D after within 1.5x D true": (v["d_within_1p5x_true"], s and s["d_within_1p5x_true"]),
    }
    print_side_by_side(table)
    med = lambda x: float(np.median(x)) if x else None  # noqa: E731
    print(f"\nD (effect cases, median): baseline {med(d_base)}, vibro after {med(d_fin)}, true model {med(d_true)}, "
          f"PySINDy after {med(d_sin)}; wall {wall:.0f} s")
    slim_rows = [{k: r.get(k) for k in ("case", "family", "found", "score", "deviation", "sindy", "regime", "error",
                                        "seconds", "spec")} for r in rows]
    out = {"benchmark": "discrepancy", "settings": res["settings"], "goals": GOALS, "wall_s": wall,
           "vibro": v, "sindy": s, "table": {k: list(x) for k, x in table.items()},
           "median_deviation": {"baseline": med(d_base), "vibro_after": med(d_fin), "true_model": med(d_true),
                                "sindy_after": med(d_sin)},
           "rows": slim_rows}
    (ROOT / "bench" / "results").mkdir(parents=True, exist_ok=True)
    path = ROOT / "bench" / "results" / "discrepancy.json"
    path.write_text(json.dumps(out, indent=1, default=float), encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
