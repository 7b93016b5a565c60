"""``vibro fit <dic.csv> --rig rig.yaml --out DIR``: identification from a DIC track alone."""

from __future__ import annotations

import argparse
from pathlib import Path

from vibro_fit.methods import METHODS
from vibro_fit.statistics import errorbar_table
from vibro_io.accel import load_accel
from vibro_io.dictrack import read_dic_csv
from vibro_io.outputs import atomic_open, prepare_output_dir, prepare_output_file
from vibro_io.results_file import read_results, write_results
from vibro_io.rig import load_rig
from vibro_model.errors import RecordingError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit", help="identify structure, flights, impacts (COR) and friction from a dic.csv")
    p.add_argument("track", help="dic.csv written by 'vibro track'")
    p.add_argument("--rig", required=True, help="rig.yaml of the recording")
    p.add_argument("--accel", help="accelerometer CSV (columns as in rig.yaml's accelerometers block)")
    p.add_argument("--out", required=True,
                   help="output folder (results.json without simulation, CSVs; created; must hold nothing but "
                        "this run's inputs unless --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the outputs of an earlier 'vibro fit' in --out (refused if it holds other files)")
    p.add_argument("--weights", choices=("none", "dic_valid"), default="none",
                   help="flight-fit weights: none (paper) or dic_valid (by the number of valid DIC points)")
    p.add_argument("--method", choices=METHODS, default="paper", help="COR method (default paper)")
    p.set_defaults(func=run)

    q = sub.add_parser("summary", help="COR mean +- std per plate across recordings (paper Fig. 14)")
    q.add_argument("results", nargs="+", help="results.json files written by 'vibro analyze' or 'vibro fit'")
    q.add_argument("--out", required=True,
                   help="output figure, e.g. fig14.png (a CSV table is written beside it); must not exist "
                        "unless --overwrite")
    q.add_argument("--overwrite", action="store_true", help="replace an existing --out figure and its CSV")
    q.set_defaults(func=run_summary)


def run(args: argparse.Namespace) -> int:
    from vibro_fit.identify import identify
    from vibro_fit.results import CSV_TABLES, RESULTS_JSON, results_model, write_csv_tables

    rig = load_rig(args.rig)
    track = read_dic_csv(args.track)
    accel = None
    if args.accel:
        if rig.accelerometers is None:
            raise RecordingError(f"{args.rig}: --accel given but rig.yaml has no 'accelerometers' block (columns)")
        accel = load_accel(args.accel, rig.accelerometers)
    inputs = [p for p in (args.track, args.rig, args.accel) if p]
    out = prepare_output_dir(args.out, overwrite=args.overwrite, owned=(RESULTS_JSON, *CSV_TABLES), command="fit",
                             inputs=inputs)
    ident = identify(track, rig, accel=accel, method=args.method, weights=args.weights)
    doc = results_model(ident, str(args.track))
    write_results(out / RESULTS_JSON, doc)
    write_csv_tables(doc, out)
    print(f"{len(ident.flights)} flights, {len(ident.impacts)} impacts, regime {ident.regime.name}; "
          f"written to {out}")
    return 0


def run_summary(args: argparse.Namespace) -> int:
    import csv

    from vibro_app.report import fig_errorbars, figure_formats

    out = Path(args.out)
    if out.suffix.lower().lstrip(".") not in figure_formats():
        raise RecordingError(f"{out}: --out needs a figure file name ending in one of "
                             f"{', '.join('.' + f for f in sorted(figure_formats()))}, e.g. fig14.png")
    table = out.with_suffix(".csv")
    for path in (out, table):
        prepare_output_file(path, overwrite=args.overwrite)
    summaries = {}
    for path in args.results:
        summ = read_results(path).cor_summary.to_dict()  # validated: errors name the file and the key
        label = Path(path).parent.name or Path(path).stem
        summaries[label] = summ
    rows = errorbar_table(summaries)
    if not rows:
        raise RecordingError("no COR in any of the results given")
    fig_errorbars(rows, out)
    with atomic_open(table, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    for r in rows:
        std = "n/a" if r["std"] is None else f"{r['std']:.4f}"
        print(f"{r['label']:<20} {r['plate']:<7} mean {r['mean']:.4f}  std {std}  n {r['n']}")
    return 0
