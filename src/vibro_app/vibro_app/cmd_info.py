"""``vibro info <recording>``: validate a recording and summarise what it holds."""

from __future__ import annotations

import argparse

from vibro_io.recording import open_recording


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="validate a recording and print what it holds")
    p.add_argument("recording", help="recording directory (rig.yaml, frames/ or video, accel.csv)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    rec = open_recording(args.recording)
    rig = rec.rig
    rows, cols = rec.frames.shape
    print(f"recording      {rec.path}")
    print(f"frames         {len(rec.frames)} x {cols}x{rows} px {rec.frames.dtype} from {rec.frames.source.name}")
    duration = len(rec.frames) / rig.camera.fps
    print(f"camera         {rig.camera.fps:g} fps, {rig.camera.mm_per_px:g} mm/px, {duration:.3f} s")
    print(f"ball           {rig.ball.diameter_mm:g} mm, {rig.ball.mass_kg:g} kg; gap {rig.structure.gap_mm:g} mm "
          f"(free play b = {rig.free_play_mm:.3f} mm)")
    print(f"excitation     {rig.excitation.frequency_hz:g} Hz (nominal)")
    accel = rec.load_accel()
    if accel is None:
        print("accelerometers none (video-only recording)")
    else:
        print(f"accelerometers {len(accel)} samples at {accel.sample_rate_hz:.0f} Hz, "
              f"{accel.t_s[0]:.4f}..{accel.t_s[-1]:.4f} s")
    return 0
