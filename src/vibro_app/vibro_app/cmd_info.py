"""``vibro info <recording | camera file> [--json]``: validate and summarise what a recording or a camera file holds."""

from __future__ import annotations

import argparse
import json
from typing import Any


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="validate a recording (or one camera file) and print what it holds")
    p.add_argument("recording", help="recording directory (rig.yaml, frames/ or video, accel file), or a camera "
                                     "file on its own (.cihx/.cih with its .mraw, .cine)")
    p.add_argument("--json", action="store_true", help="print one JSON object (keys: docs/commands.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from .recording_info import describe  # OpenCV, scipy and the texture check: only when a recording is read

    info = describe(args.recording)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        print("\n".join(human_lines(info)))
    return 0


def _num(value: float | None, digits: int = 6, unit: str = "") -> str:
    return "unknown" if value is None else f"{value:.{digits}g}{unit}"


def human_lines(info: dict[str, Any]) -> list[str]:
    """The info dict as aligned lines for a terminal (the same values as --json)."""
    lines = [f"source         {info['source']} ({info['kind']})"]
    frames = f"frames         {info['frames']} x {info['width_px']}x{info['height_px']} px"
    if info.get("images") is not None and info["images"] != info["frames"]:
        frames += f" ({info['images']} images in the file)"
    if info.get("dropped_frames"):
        frames += f", {info['dropped_frames']} dropped by the camera's clock"
    lines.append(frames)
    rate = f"time base      {_num(info['fps'], 8)} frames/s from {info['fps_source']}"
    record, fps = info.get("record_fps"), info.get("fps")
    if record is not None and (fps is None or abs(record - fps) > 1e-3 * record):
        rate += f" (header: {info['record_fps']:g} frames/s, save step {info.get('save_step', 1)})"
    if info.get("fps_candidates"):
        rate += f"; candidates {' or '.join(f'{c:g}' for c in info['fps_candidates'])}: set camera.fps"
    lines.append(rate)
    lines.append(f"duration       {_num(info['duration_s'], 6, ' s')}; frame 0 at {_num(info['t0_s'], 9, ' s')} from "
                 f"the trigger; started {info.get('start_time_utc') or 'unknown'}")
    for note in info.get("time_base_notes") or []:
        lines.append(f"  note: {note}")
    depth, gray, noise = info["bit_depth"], info["frame0_gray"], info["noise_gray"]
    lines.append(f"pixels         {depth['effective']} bits in {depth['container']}; frame 0 gray {gray['min']}.."
                 f"{gray['max']} of {gray['full_scale']}, mean {gray['mean']:.1f}, "
                 f"{100 * gray['saturated_share']:.1f} % saturated")
    lines.append(f"noise          {noise['sigma']:.3g} gray levels ({noise['method']})")
    if info.get("dic_sigma_px"):
        lines.append("DIC sigma      " + ", ".join(f"{body} {value:.3g} px" for body, value in
                                                    info["dic_sigma_px"].items()) + " (worst subset, predicted)")
    rig = info.get("rig")
    if rig:
        lines.append(f"rig            {rig['mm_per_px']:g} mm/px; ball {rig['ball_diameter_mm']:g} mm, "
                     f"{rig['ball_mass_kg']:g} kg; gap {rig['gap_mm']:g} mm (free play b = {rig['free_play_mm']:.3f} "
                     f"mm); excitation {rig['excitation_hz']:g} Hz (nominal)"
                     + (f"; axis {rig['axis_tilt_deg']:g} deg from vertical (setup.axis_tilt_deg: gravity along it "
                        f"{rig['axis_gravity_mps2']:.3g} m/s^2)" if rig.get("axis_tilt_deg") else ""))
    if "accelerometers" in info:
        acc = info["accelerometers"]
        if acc is None:
            lines.append("accelerometers none (video-only recording)")
        else:
            lines.append(f"accelerometers {acc['samples']} samples at {acc['rate_hz']:.6g} Hz in {acc['unit']}, "
                         f"{acc['t_start_s']:.6f}..{acc['t_end_s']:.6f} s; {acc['overlap_s']:.6f} s overlap the video")
    return lines
