"""``vibro prove``: blind proof of the discrepancy analysis (see :mod:`vibro_eval.prove`)."""

from __future__ import annotations

import argparse
import sys

from vibro_model.errors import RecordingError


def register(sub) -> None:
    """Add the ``prove`` subcommand to the ``vibro`` subparsers."""
    p = sub.add_parser(
        "prove", help="prove the discrepancy analysis blind on synthetic recordings with concealed effects",
        description="Synthesize recordings with randomly drawn effects (and controls), run 'vibro analyze' on "
                    "each recording directory only, score the discrepancy findings against the truth files: "
                    "confusion matrix, parameter errors, D_r before/after vs the true model's and the paper's D, "
                    "per-impact COR error vs the truth; PySINDy side by side when installed. Ranges: see "
                    "vibro_eval/prove.py.")
    p.add_argument("--cases", type=int, default=None,
                   help="number of recordings (default 8: each effect + a control); not with --magnitudes")
    p.add_argument("--seed", type=int, default=0, help="random seed of the draws")
    p.add_argument("--out", default=None, help="work directory (recordings, results, proof.json); default: temp")
    p.add_argument("--frames", type=int, default=None,
                   help="frames per recording (1000 fps; default 500, with --harder 1000)")
    p.add_argument("--pairs", type=float, default=0.0, metavar="P",
                   help="probability that an effect case gets a second, compatible effect (default 0)")
    p.add_argument("--evidence", action="store_true",
                   help="the evidence set: --magnitudes 2 --controls 3 --invented --cor-scatter 0.01,0.02 "
                        "--noise 1,3 --blur-share 0.5 (each can still be given)")
    p.add_argument("--magnitudes", type=int, default=None, metavar="M",
                   help="each catalogue effect at M magnitudes (its range cut in M parts) plus --controls "
                        "controls, instead of --cases (default 0: off)")
    p.add_argument("--controls", type=int, default=None, metavar="N", help="controls with --magnitudes (default 3)")
    p.add_argument("--invented", action="store_true",
                   help="with --magnitudes: also the synth's out-of-catalogue effects (cor_drift, structure_tone, "
                        "plate_step, plate_creep, position_force, cor_parity), each at M magnitudes; the analysis must "
                        "report them as 'unexplained'")
    p.add_argument("--cor-scatter", default=None, metavar="LOW[,HIGH]",
                   help="per-impact COR scatter sigma drawn per case in [LOW, HIGH] (default 0)")
    p.add_argument("--noise", default=None, metavar="LOW,HIGH", help="read noise in gray levels (default 1,4)")
    p.add_argument("--blur-share", type=float, default=None, metavar="P",
                   help="probability of motion blur (0.5 ms exposure) per case (default 0)")
    p.add_argument("--harder", action="store_true",
                   help="the harder rigs instead: near-chatter with sticking (COR 0.4-0.6), runs of 2-6 dropped "
                        "frames hiding impacts or inside flights (with and without accelerometers), Coulomb friction "
                        "with drops, position_force and cor_parity (out of the catalogue), a control; 13 cases, or "
                        "--cases N of them. Scored per case: impact recall >= 98 %%, no invented impact, every gap's "
                        "impact found (in_gap) or counted, mean |COR error| <= 0.002, findings vs truth, D_r lowered; "
                        "prints one row per case (families: vibro_eval/harder.py)")
    p.add_argument("--no-sindy", action="store_true", help="skip the PySINDy comparison")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _range(text: str | None, option: str, default: tuple[float, float]) -> tuple[float, float]:

    if text is None:
        return default
    try:
        vals = [float(x) for x in str(text).split(",")]
    except ValueError:
        vals = []
    if len(vals) == 1:
        vals = vals * 2
    if len(vals) != 2:
        raise RecordingError(f"{option} must be LOW[,HIGH] (numbers), got {text!r}")
    return vals[0], vals[1]


def draws_of(args: argparse.Namespace):
    """The :class:`~vibro_eval.prove.Draws` of the command line (``--evidence`` fills what is not given)."""
    from .prove import EVIDENCE, INVENTED, Draws

    base = EVIDENCE if args.evidence else Draws()
    magnitudes = base.magnitudes if args.magnitudes is None else args.magnitudes
    if magnitudes and args.cases is not None:
        raise RecordingError("give either --cases or --magnitudes/--evidence, not both")
    if not magnitudes and (args.invented or args.controls is not None):
        raise RecordingError("--invented and --controls need --magnitudes (or --evidence)")
    return Draws(cor_scatter=_range(args.cor_scatter, "--cor-scatter", base.cor_scatter),
                 noise_gray=_range(args.noise, "--noise", base.noise_gray),
                 blur_share=base.blur_share if args.blur_share is None else args.blur_share,
                 magnitudes=magnitudes, controls=base.controls if args.controls is None else args.controls,
                 invented=INVENTED if args.invented else base.invented)


def run_harder(args: argparse.Namespace) -> int:

    from .harder import prove_harder

    given = [o for o, v in (("--evidence", args.evidence), ("--magnitudes", args.magnitudes is not None),
                            ("--controls", args.controls is not None), ("--invented", args.invented),
                            ("--pairs", args.pairs != 0.0), ("--cor-scatter", args.cor_scatter is not None),
                            ("--noise", args.noise is not None), ("--blur-share", args.blur_share is not None)) if v]
    if given:
        raise RecordingError(f"--harder draws its own cases; not with {', '.join(given)}")
    res = prove_harder(args.seed, args.out, 1000 if args.frames is None else args.frames, args.cases,
                       sindy=not args.no_sindy, progress=not args.no_progress and sys.stderr.isatty())
    print("\n".join(res["table"]))
    print(f"wrote {res['settings']['work_dir']}/proof.json")
    return 0


def run(args: argparse.Namespace) -> int:
    from .prove import ProofCases, format_summary, prove

    if args.harder:
        return run_harder(args)

    if not 0.0 <= args.pairs <= 1.0:

        raise RecordingError(f"--pairs must be in [0, 1], got {args.pairs}")
    draws = draws_of(args)
    frames = 500 if args.frames is None else args.frames
    selection = ProofCases(cases=8 if args.cases is None else args.cases, seed=args.seed, frames=frames,
                           pairs=args.pairs, draws=draws)
    res = prove(selection, args.out, sindy=not args.no_sindy, progress=not args.no_progress and sys.stderr.isatty())
    print(format_summary(res["vibro"], "vibro discrepancy analysis"))
    if "sindy" in res:
        print(format_summary(res["sindy"], f"PySINDy {res['settings']['pysindy']} on the same data"))
    for r in res["rows"]:
        if "error" in r:
            print(f"   case {r['case']} ({r['family']}): analyze failed: {r['error']}")
    print(f"wrote {res['settings']['work_dir']}/proof.json")
    return 0
