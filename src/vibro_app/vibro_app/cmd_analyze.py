"""``vibro analyze <recording> --out DIR``: DIC + identification + simulation + report."""

from __future__ import annotations

import argparse
import sys

from vibro_app.findings_text import findings_lines
from vibro_dic.cluster import add_cluster_args
from vibro_fit.methods import METHODS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("analyze", help="track, identify, simulate; write results.json, CSVs and report.html")
    p.add_argument("recording", help="recording directory (rig.yaml, frames/ or video, accel.csv)")
    p.add_argument("--out", required=True, help="output folder (created; must be empty unless --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the outputs of an earlier 'vibro analyze' in --out (refused if it holds other files)")
    p.add_argument("--method", choices=METHODS, default="paper",
                   help="COR method: paper (Eq. 15-16, default) or joint (flights constrained to meet on the "
                        "plate, friction shrunk towards the recording's mean)")
    p.add_argument("--weights", choices=("none", "dic_valid"), default="none",
                   help="flight-fit weights: none (paper) or dic_valid (by the number of valid DIC points)")
    p.add_argument("--track", help="use this dic.csv instead of running DIC (frames are then not read)")
    p.add_argument("--dic-method", default="icgn", help="DIC sub-pixel method (icgn, parabolic)")
    p.add_argument("--no-report", action="store_true", help="skip figures and report.html")
    add_cluster_args(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from vibro_app.analyze import COMMAND_LINE, DicPlan, FitPlan, analyze_recording  # the pipeline: when it runs

    progress = not args.no_progress and sys.stderr.isatty()
    dic = DicPlan(method=args.dic_method, workers=args.workers, scheduler=args.scheduler)
    fit = FitPlan(method=args.method, weights=args.weights)
    token = COMMAND_LINE.set(tuple(getattr(args, "command_line", None) or ()) or None)  # provenance's command
    try:
        doc = analyze_recording(args.recording, args.out, progress=progress, fit=fit, track_csv=args.track, dic=dic,
                                report=not args.no_report, overwrite=args.overwrite)
    finally:
        COMMAND_LINE.reset(token)
    summ = doc["cor_summary"]
    sim = doc["simulation"]

    def f(v, spec):
        return "n/a" if v is None else format(v, spec)

    print(f"results        {args.out}/results.json")
    print(f"regime         {doc['regime']['name']}; {len(doc['flights'])} flights, {len(doc['impacts'])} impacts")
    s = doc["structure"]
    if doc.get("motion"):
        print(f"motion         {doc['motion']['message']}")
    print(f"structure      A = {f(s['amplitude_mm'], '.4f')} mm, f = {f(s['frequency_hz'], '.4f')} Hz"
          + ("" if s.get("moving", True) else " (does not move beyond DIC noise)"))
    acc = doc.get("accelerometers") or {}
    if acc.get("clock_offset"):
        print(f"accelerometers {acc['n_impacts']} impacts; {acc['clock_offset']['message']}")
    for r in doc.get("rig_consistency", []):
        print(f"rig.yaml       inconsistent: {r['message']}")
    for finding in (doc.get("consistency") or {}).get("findings", []):
        print(f"consistency    {finding['message']}")
    for plate in ("bottom", "top"):
        d = summ[plate]
        print(f"COR {plate:<7}    mean {f(d['mean'], '.4f')}  std {f(d['std'], '.4f')}  n {d['n']}")
    print(f"deviation D    COR model {f(sim['cor_model']['deviation'], '.4f')}, "
          f"Hertz model {f(sim['hertz_model']['deviation'], '.4f')}")
    for line in findings_lines(doc.get("discrepancy")):
        print(line)
    for w in doc.get("warnings", []):
        print(f"warning: {w}", file=sys.stderr)
    return 0
