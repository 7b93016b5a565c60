"""``vibro synth``: write a synthetic recording with ground truth beside it."""

from __future__ import annotations

import argparse
import logging
import sys

from vibro_sim.synth import EFFECT_NAMES, EFFECTS, SynthConfig, SynthError, parse_effect_args
from vibro_sim.synth.invented import INVENTED_EFFECTS, INVENTED_HELP
from vibro_sim.synth.scenario import HORIZONTAL_ACCEL_MPS2, HORIZONTAL_FROM_DEG

log = logging.getLogger(__name__)


def _effects_help() -> str:
    parts = [f"{name} ({', '.join(f'{k}={d:g}' for k, (d, _, _) in spec.items())})"
             for name, spec in EFFECTS.items()]
    invented = [f"{name} ({', '.join(f'{k}={d:g}' for k, (d, _, _) in spec.items())}: {INVENTED_HELP[name]})"
                for name, spec in INVENTED_EFFECTS.items()]
    from vibro_sim.synth.invented import DRIVE_EFFECTS, DRIVE_HELP

    drive = [f"{name} ({', '.join(f'{k}={d:g}' for k, (d, _, _) in spec.items())}: {DRIVE_HELP[name]})"
             for name, spec in DRIVE_EFFECTS.items()]
    return ("; ".join(parts) + ". Invented effects OUTSIDE the discrepancy catalogue (no term models them: "
            "the analysis must report them as 'unexplained', located): " + "; ".join(invented)
            + ". The drive itself, not ball physics (results.json 'drive'): " + "; ".join(drive))


def register(sub) -> None:
    """Add the ``synth`` subcommand to the ``vibro`` subparsers."""
    p = sub.add_parser(
        "synth", help="write a synthetic recording with known ground truth",
        description="Simulate the ball-in-cavity rig and write a complete recording (rig.yaml, "
                    "frames/, accel.csv) to --out, and the ground truth to OUT.truth.json beside it. "
                    "Effects and default parameters: " + _effects_help(),
    )
    p.add_argument("--out", required=True, help="new recording folder (created; must be empty unless --overwrite)")
    p.add_argument("--effect", action="append", metavar="NAME",
                   help=f"physics the baseline leaves out; repeatable ({', '.join(EFFECT_NAMES)})")
    p.add_argument("--param", action="append", metavar="KEY=VALUE",
                   help="effect parameter (contract names, SI), e.g. force_n=2e-4; repeatable")
    p.add_argument("--seed", type=int, default=0, help="random seed (phase, speckle, noise, scatter)")
    p.add_argument("--frequency-hz", type=float, default=22.0, help="shaker frequency (Hz)")
    p.add_argument("--cor", type=float, default=None, metavar="E",
                   help="the baseline's constant COR (default 0.7); with a drive near g, e.g. --cor 0.5 "
                        "--accel-mps2 13 --frequency-hz 10: chatter with sticking on the lower plate")
    p.add_argument("--accel-mps2", "--accel-ms2", dest="accel_mps2", type=float, default=None,
                   help="shaker acceleration amplitude (m/s^2; default 27: two impacts per cycle; 40 with "
                        "--axis-tilt-deg 78 or more, where no gravity along the axis holds that rhythm)")
    p.add_argument("--axis-tilt-deg", type=float, default=0.0, metavar="THETA",
                   help="the rig's motion axis from vertical as mounted, 0..90 (0 vertical, default; 90 horizontal: "
                        "the paper's Fig. 11 study): written to rig.yaml setup.axis_tilt_deg and simulated with "
                        "gravity g cos(THETA) along the axis. --effect gravity_tilt --param tilt_deg=T conceals a "
                        "true tilt T from vertical instead (e.g. 50 on a rig declared at 45). A horizontal rig's "
                        "guide rods: add --effect coulomb_friction")
    p.add_argument("--noise", type=float, default=2.0, metavar="GRAY", help="read noise sigma (gray levels)")
    p.add_argument("--blur", action="store_true", help="motion blur over a 0.5 ms exposure")
    p.add_argument("--clock-offset-ms", type=float, default=0.0, metavar="T",
                   help="accelerometer clock minus camera clock (ms), at camera time 0")
    p.add_argument("--daq-clock-ppm", type=float, default=0.0, metavar="PPM",
                   help="the accelerometer DAQ's clock runs fast by PPM against the camera's (a crystal's error, "
                        "e.g. 200; negative: slow): accel.csv time = camera time + offset + PPM 1e-6 camera time "
                        "(default 0)")
    p.add_argument("--cor-scatter", type=float, default=0.0, metavar="SIGMA",
                   help="per-impact COR scatter of every scenario: each impact's COR drawn N(law, SIGMA), e.g. "
                        "0.015 as the paper's Fig. 14-16 show (default 0: no scatter)")
    p.add_argument("--spin-rad-s", type=float, default=0.0, metavar="W",
                   help="the ball's in-plane spin per flight (rad/s, + counter-clockwise on screen; default 0)")
    p.add_argument("--spin-sigma-rad-s", type=float, default=0.0, metavar="SIGMA",
                   help="each impact sets a new spin N(--spin-rad-s, SIGMA) (default 0)")
    p.add_argument("--spin-cor-coupling", type=float, default=0.0, metavar="K",
                   help="COR change per rad/s of spin change at an impact (s/rad; default 0)")
    p.add_argument("--ball-surface", choices=("speckle", "shiny", "plain"), default="speckle",
                   help="speckle (default); shiny: a dark glossy sphere without texture whose specular "
                        "highlight stays fixed relative to the light (real footage); plain: a backlit dark disc "
                        "with a sharp outline, tracked by its outline (rig.yaml dic.ball_method: outline)")
    p.add_argument("--light-deg", type=float, default=30.0, metavar="DEG",
                   help="shiny ball: the light's angle from the camera axis, towards the image top (default 30; "
                        "the highlight sits R sin(DEG/2) above the ball's centre)")
    p.add_argument("--jpeg-quality", type=int, default=0, metavar="Q",
                   help="pass every frame through JPEG at quality Q (1-100) before writing it (lossy video; "
                        "default 0: none)")
    p.add_argument("--lens-k1", type=float, default=0.0, metavar="K",
                   help="see the frames through a lens with radial distortion k1 (plumb_bob; fx = fy = 1000 px, "
                        "principal point at the image centre; -0.18: a barrel lens whose scale at the lower plate "
                        "is ~1.5 %% below the centre's), and write its calibration camera_info.yaml, named in "
                        "rig.yaml camera.calibration (default 0: no lens)")
    p.add_argument("--lens-k2", type=float, default=0.0, metavar="K", help="the lens's k2 (default 0)")
    p.add_argument("--no-calibration-file", action="store_true",
                   help="with --lens-k1/--lens-k2: write no camera_info.yaml and leave camera.calibration out of "
                        "rig.yaml (a lab that forgot to calibrate its camera)")
    p.add_argument("--frames", type=int, default=1500, help="number of frames (1000 fps)")
    p.add_argument("--still", action="store_true", help="nothing moves (noise study)")
    p.add_argument("--drift", action="store_true", help="with --still: slow camera drift")
    p.add_argument("--tiff16", action="store_true", help="16-bit TIFF frames instead of 8-bit PNG")
    p.add_argument("--bits12", action="store_true",
                   help="16-bit TIFF frames holding a 12-bit camera's codes (at the top of the word, as Photron)")
    p.add_argument("--no-accel", action="store_true", help="video-only recording")
    p.add_argument("--lab-files", action="store_true",
                   help="write what a lab's camera and DAQ give: the video as an 8-bit Photron MRAW (video.mraw + "
                        "video.cih) and the accelerometers as an NI TDMS (accel.tdms, 50 kHz waveform channels) "
                        "instead of frames/ and accel.csv, and no rig.yaml: make it with `vibro init` (the truth "
                        "file's lab_files names the accelerometers block to add for the TDMS)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier synthetic recording in --out and its truth file (refused if --out "
                        "holds other files)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def config_from_args(args: argparse.Namespace) -> SynthConfig:
    """Build a :class:`SynthConfig` from parsed CLI arguments (raises SynthError)."""
    if args.drift and not args.still:
        raise SynthError("--drift needs --still")
    effects = parse_effect_args(args.effect, args.param)
    kw = {}
    if args.accel_mps2 is not None:
        kw["accel_mps2"] = args.accel_mps2
    if args.cor is not None:
        kw["cor"] = args.cor
    if getattr(args, "no_calibration_file", False) and not (args.lens_k1 or args.lens_k2):
        raise SynthError("--no-calibration-file needs a lens (--lens-k1 or --lens-k2)")
    kw.update(lens_k1=getattr(args, "lens_k1", 0.0), lens_k2=getattr(args, "lens_k2", 0.0),
              lens_calibration_file=not getattr(args, "no_calibration_file", False))
    tilt = getattr(args, "axis_tilt_deg", 0.0)
    kw["axis_tilt_deg"] = tilt
    if args.accel_mps2 is None and tilt >= HORIZONTAL_FROM_DEG:
        kw["accel_mps2"] = HORIZONTAL_ACCEL_MPS2
    return SynthConfig(effects=effects, seed=args.seed, frequency_hz=args.frequency_hz,
                       noise_gray=args.noise, blur=args.blur, clock_offset_s=args.clock_offset_ms * 1e-3,
                       daq_clock_ppm=args.daq_clock_ppm,
                       frames=args.frames, still=args.still, drift=args.drift, tiff16=args.tiff16,
                       bits12=args.bits12,
                       accel=not args.no_accel, cor_scatter=args.cor_scatter, spin_rad_s=args.spin_rad_s,
                       spin_sigma_rad_s=args.spin_sigma_rad_s,
                       spin_cor_coupling_s_per_rad=args.spin_cor_coupling, ball_surface=args.ball_surface,
                       light_deg=args.light_deg, jpeg_quality=args.jpeg_quality, **kw)


def run(args: argparse.Namespace) -> int:
    from vibro_sim.synth.write import synthesize, truth_path  # renderer and simulator: loaded only for `vibro synth`

    cfg = config_from_args(args)
    truth = synthesize(args.out, cfg, overwrite=args.overwrite,
                       progress=False if args.no_progress else None, lab_files=args.lab_files)
    n = len(truth["impacts"])
    print(f"wrote {args.out} ({cfg.frames} frames, {n} impacts) and {truth_path(args.out)}",
          file=sys.stdout)
    return 0
