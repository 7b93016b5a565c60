"""``vibro prove``: blind proof of the discrepancy analysis (see :mod:`vibro_eval.prove`)."""

from __future__ import annotations

import argparse
import sys


def register(sub) -> None:
    """Add the ``prove`` subcommand to the ``vibro`` subparsers."""
    p = sub.add_parser(
        "prove", help="prove the discrepancy analysis blind on synthetic recordings with concealed effects",
        description="Synthesize recordings with randomly drawn effects (and controls), run 'vibro analyze' on "
                    "each recording directory only, score the discrepancy findings against the truth files: "
                    "confusion matrix, parameter errors, D before/after vs the true model's D; PySINDy side by "
                    "side when installed. Ranges: see vibro_eval/prove.py.")
    p.add_argument("--cases", type=int, default=8, help="number of recordings (default 8: each effect + a control)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the draws")
    p.add_argument("--out", default=None, help="work directory (recordings, results, proof.json); default: temp")
    p.add_argument("--frames", type=int, default=500, help="frames per recording (1000 fps; default 500)")
    p.add_argument("--pairs", type=float, default=0.0, metavar="P",
                   help="probability that an effect case gets a second, compatible effect (default 0)")
    p.add_argument("--no-sindy", action="store_true", help="skip the PySINDy comparison")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .prove import format_summary, prove

    if not 0.0 <= args.pairs <= 1.0:
        from vibro_io.errors import RecordingError

        raise RecordingError(f"--pairs must be in [0, 1], got {args.pairs}")
    res = prove(args.cases, args.seed, args.out, args.frames, sindy=not args.no_sindy,
                progress=not args.no_progress and sys.stderr.isatty(), pairs=args.pairs)
    print(format_summary(res["vibro"], "vibro discrepancy analysis"))
    if "sindy" in res:
        print(format_summary(res["sindy"], f"PySINDy {res['settings']['pysindy']} on the same data"))
    for r in res["rows"]:
        if "error" in r:
            print(f"   case {r['case']} ({r['family']}): analyze failed: {r['error']}")
    print(f"wrote {res['settings']['work_dir']}/proof.json")
    return 0
