"""``vibro campaign <folder or list> --out DIR``: every recording analysed on a Dask cluster, one report.

Exit code: 0 when every run was analysed (now or resumed), 1 when the campaign ran but at least one run
failed (each named with its reason in the summary and campaign.json), 2 for bad input of the campaign
itself (no recordings, an unusable --out, a bad --workers, an unreachable --scheduler).
"""

from __future__ import annotations

import argparse
import sys

from vibro_app.campaign.engine import run_campaign
from vibro_app.campaign.report import CAMPAIGN_CSV, CAMPAIGN_JSON, REPORT_HTML
from vibro_dic.cluster import add_cluster_args, default_workers
from vibro_fit.methods import METHODS

EXIT_RUN_FAILED = 1


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("campaign", help="analyse every recording of a folder or list on a Dask cluster; "
                                        "one campaign report (resumes; a bad recording does not stop it)")
    p.add_argument("source", help="a folder (every folder below it holding rig.yaml is a run) or a text file "
                                  "listing recording folders, one per line")
    p.add_argument("--out", required=True, help="campaign folder: OUT/<run>/ holds each run's 'vibro analyze' "
                                               "outputs; campaign.json, campaign.csv, figures, report.html")
    add_cluster_args(p, workers_help=f"worker processes of the local Dask cluster (default: the CPU cores, here "
                                     f"{default_workers()})",
                     scheduler_help="use the existing Dask cluster at ADDRESS (e.g. tcp://host:8786); its workers "
                                    "must see the recordings' and --out's paths")
    p.add_argument("--method", choices=METHODS, default="paper", help="COR method (as vibro analyze)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    doc = run_campaign(args.source, args.out, workers=args.workers, scheduler=args.scheduler, method=args.method,
                       progress=not args.no_progress and sys.stderr.isatty())
    s = doc["summary"]
    print(f"campaign       {s['n_runs']} runs: {s['n_ok']} analysed ({s['n_resumed']} resumed), "
          f"{s['n_failed']} failed, {s['n_flagged']} flagged")
    for f in s["failed"]:
        print(f"failed         {f['name']}: {f['reason']}")
    for f in s["flagged"]:
        for g in f["flags"]:
            print(f"flagged        {f['name']}: {g['plate']} COR z = {g['z']:+.1f} against the median "
                  f"{g['group_median']:.4f} of {g['group_n']} runs at {g['excitation']}")
    print(f"report         {args.out}/{REPORT_HTML}, {CAMPAIGN_CSV}, {CAMPAIGN_JSON}")
    return EXIT_RUN_FAILED if s["n_failed"] else 0
