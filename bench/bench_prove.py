"""Evidence for the discrepancy analysis: blind on realistic synthetic recordings, vibro vs PySINDy.

One ``vibro prove --evidence`` run (vibro_eval/prove.py: ``EVIDENCE``): per-impact COR scatter 0.01-0.02
on every case, read noise 1-3 gray levels, motion blur (0.5 ms exposure) on about half the cases, each of
the 7 catalogue effects at two magnitudes (weaker and stronger half of its documented range), the five
out-of-catalogue effects of the synthetic rig (cor_drift, structure_tone, plate_step, position_force,
cor_parity) at two magnitudes, and 3 controls: 27 recordings. ``vibro analyze`` runs on each recording
directory alone; the truth is read only to score. Goals: effects identified >= 95 % (out-of-catalogue only
as ``unexplained`` with a location), no finding on a control, every correct finding improving the model (restarted
deviation D_r lower; a COR law, which D_r cannot see: COR variance explained above chance),
per-impact COR error vs the truth <= 0.002 with an effect and <= 0.001 without; the paper's D beside D_r.

Baselines measured in the same run: PySINDy given the same measured data (the identification's flights,
impacts and structure track; a library of the same terms) scored the same way (ratio PySINDy / vibro),
and the paper's Eq. 16 CORs against the final model's (ratio paper / final model).

Run: scripts/py bench/bench_prove.py [--frames 1000] [--seed 2026] [--magnitudes 2] [--controls 3]
     [--only 12,13,6] -> table + bench/results/prove.json
(``--only``: just those case numbers of the drawn set, each drawn exactly as in the whole run, e.g. to rerun
some cases on a loaded machine; settings.only in the JSON says so)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

from side_by_side import fmt, print_side_by_side, ratio  # noqa: E402

from vibro_eval.prove import EVIDENCE, GOALS, ProofCases, format_family_table, format_summary, prove  # noqa: E402
from vibro_model.errors import RecordingError  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--magnitudes", type=int, default=EVIDENCE.magnitudes)
    ap.add_argument("--controls", type=int, default=EVIDENCE.controls)
    ap.add_argument("--out", default="/tmp/vibro_bench_prove")
    ap.add_argument("--only", default=None, help="comma-separated case numbers of the drawn set to run (default all)")
    args = ap.parse_args(argv)
    try:
        only = None if args.only is None else tuple(int(x) for x in args.only.split(",") if x.strip())
    except ValueError:
        print(f"--only must be comma-separated case numbers, got {args.only!r}", file=sys.stderr)
        return 2
    draws = replace(EVIDENCE, magnitudes=args.magnitudes, controls=args.controls)
    t0 = time.perf_counter()
    try:
        res = prove(ProofCases(seed=args.seed, frames=args.frames, draws=draws, only=only), out=args.out,
                    sindy=True, progress=sys.stderr.isatty())
    except RecordingError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    wall = time.perf_counter() - t0
    v, s = res["vibro"], res.get("sindy")
    print(format_summary(v, f"vibro ({res['settings']['cases']} cases, {args.frames} frames)"))
    if s:
        print(format_summary(s, f"PySINDy {res['settings']['pysindy']} on the same data"))
    table = {
        "effects identified (%)": (v["identified_pct"], s and s["identified_pct"]),
        "out of catalogue unexplained": (f"{v['out_of_catalogue_unexplained']}/{v['out_of_catalogue']}",
                                         s and f"{s['out_of_catalogue_unexplained']}/{s['out_of_catalogue']}"),
        "out of catalogue located right": (f"{v['out_of_catalogue_located']}/{v['out_of_catalogue']}",
                                           s and f"{s['out_of_catalogue_located']}/{s['out_of_catalogue']}"),
        "spurious findings (effect cases)": (v["spurious_findings_on_effect_cases"],
                                             s and s["spurious_findings_on_effect_cases"]),
        "controls without finding": (f"{v['controls_without_finding']}/{v['controls']}",
                                     s and f"{s['controls_without_finding']}/{s['controls']}"),
        "main parameter error, median (%)": (v["parameter_error_median_pct"], s and s["parameter_error_median_pct"]),
        "main parameter error, max (%)": (v["parameter_error_max_pct"], s and s["parameter_error_max_pct"]),
        "paper D after / true model's, max": (v["d_final_over_true_max"], s and s["d_final_over_true_max"]),
    }
    print_side_by_side(table)
    cor = {
        "COR error max, effects": (v["cor_error_max_effects"], v["cor_error_max_effects_paper"],
                                   GOALS["cor_error_effects"]),
        "COR error max, controls": (v["cor_error_max_controls"], v["cor_error_max_controls_paper"],
                                    GOALS["cor_error_controls"]),
    }
    print(f"\n{'per-impact COR vs truth':38} {'final model':>14} {'paper Eq. 16':>14} {'paper/final':>14} {'goal':>8}")
    for k, (a, b, g) in cor.items():
        q = ratio(b, a)
        print(f"{k:38} {fmt(a):>14} {fmt(b):>14} {('' if q is None else f'{q:.3g}'):>14} {g:>8}")
    print(f"correct findings improving the model (D_r lower; COR laws: variance share above chance): "
          f"{v['correct_findings_improving']}/{v['correct_findings']}; "
          f"unmatched impacts {v['unmatched_impacts']}; wall {wall:.0f} s")
    print("\nper family (medians of D in %, COR errors in 1e-3):")
    print(format_family_table(v["families"]))
    slim_rows = [{k: r.get(k) for k in ("case", "family", "found", "score", "findings", "cor_error", "cor_method",
                                        "contact_scatter", "deviation", "sindy", "regime", "error", "seconds", "spec")}
                 for r in res["rows"]]
    out = {"benchmark": "prove", "settings": res["settings"], "goals": GOALS, "wall_s": wall,
           "vibro": v, "sindy": s, "table": {k: list(x) for k, x in table.items()},
           "cor_error": {k: {"final_model": a, "paper": b, "goal": g} for k, (a, b, g) in cor.items()},
           "rows": slim_rows}
    (ROOT / "bench" / "results").mkdir(parents=True, exist_ok=True)
    path = ROOT / "bench" / "results" / "prove.json"
    path.write_text(json.dumps(out, indent=1, default=float), encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
