"""``vibro init <video or frames> --ball-diameter-mm D --gap-mm G [--fps F]``: propose a rig.yaml.

Finds the ball, the plates and a textured structure patch (:mod:`vibro_dic.init_rig`), writes a
commented rig.yaml (what was measured, how sure) that ``vibro analyze`` accepts, and a preview PNG
of frame 0 with the ROIs, mesh points and a scale bar. Refuses (exit 2, one line) what it cannot find.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import cv2
import numpy as np

from vibro_app.init_accel import AccelChoice, AccelRequest, choose_accel
from vibro_dic.mesh import mesh_points
from vibro_io.camera_files import open_camera_file
from vibro_io.frames import CAMERA_FILE_SUFFIXES, FrameSequence, find_frames_source
from vibro_io.outputs import atomic_path, atomic_write_text, prepare_output_file
from vibro_io.rig import CameraConfig, _RigLoader, check_rois_in_image, parse_rig
from vibro_model.errors import RecordingError

MAX_FRAMES_EXAMINED = 400
# Not measurable from video: the paper's Test 1 rig (silicon nitride ball, aluminium plates); edit for yours.
ASSUMED = {"ball_mass_kg": 1.82e-4, "ball_youngs_modulus_pa": 3.1e11, "ball_poisson_ratio": 0.27,
           "structure_mass_kg": 0.663, "structure_youngs_modulus_pa": 7.0e10, "structure_poisson_ratio": 0.33}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("init", help="find ball, plates and scale in a video and write a rig.yaml",
                       description="Find the ball, the plates and a textured patch of the structure in a video "
                                   "or frames folder; write a commented rig.yaml with ROIs and scale (from the "
                                   "ball's diameter, cross-checked with the gap) and a preview PNG.")
    p.add_argument("source", help="recording folder (frames/ or video.*), a frames folder, or a video/camera file")
    p.add_argument("--ball-diameter-mm", type=float, required=True, help="the ball's diameter (mm)")
    p.add_argument("--gap-mm", type=float, required=True, help="distance between the two impact surfaces (mm)")
    p.add_argument("--fps", type=float, default=None, help="frame rate (default: the camera file's header)")
    p.add_argument("--frequency-hz", type=float, default=None,
                   help="shaker frequency (default: estimated from the structure's motion)")
    p.add_argument("--axis-tilt-deg", type=float, default=0.0, metavar="THETA",
                   help="the rig's motion axis from vertical as mounted, 0..90 (0 vertical, default; 45 tilted; 90 "
                        "horizontal): rig.yaml setup.axis_tilt_deg; not measurable from the video")
    p.add_argument("--subset-px", type=int, default=31, help="DIC subset side (odd, px; default 31)")
    p.add_argument("--mesh-step-px", type=int, default=10, help="mesh point spacing (px; default 10)")
    p.add_argument("--out", default=None, help="rig.yaml to write (default: rig.yaml in the recording folder)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier rig.yaml and preview")
    p.add_argument("--accel", default=None, metavar="FILE",
                   help="the accelerometer file of this take in the recording folder (default: the one accel.csv "
                        "or *.tdms there; rig.yaml's accelerometers block names it)")
    p.add_argument("--accel-upper", default=None, metavar="NAME",
                   help="the upper plate's column (CSV) or channel (TDMS) (default: the one named upper/top)")
    p.add_argument("--accel-lower", default=None, metavar="NAME",
                   help="the lower plate's column (CSV) or channel (TDMS) (default: the one named lower/bottom)")
    p.add_argument("--no-accel", action="store_true",
                   help="video only: no accelerometers block even when an accelerometer file is there")
    p.set_defaults(func=run)


def _recording_dir(source: Path) -> Path:
    """The folder a rig.yaml for ``source`` belongs in: the recording folder holding frames/ or video.*."""
    if source.is_dir():
        try:
            find_frames_source(source)
            return source
        except RecordingError:
            return source.parent
    return source.parent


def _frames_source(source: Path) -> Path:
    if source.is_dir():
        try:
            return find_frames_source(source)
        except RecordingError:
            return source  # a folder of frame files itself
    if not source.exists():
        raise RecordingError(f"{source}: no such video file or frames folder")
    return source


def _fps(args: argparse.Namespace, src: Path) -> float:
    """--fps, checked against a camera file's time base (its stamps or header), else the file's rate."""
    if args.fps is not None and not (math.isfinite(args.fps) and args.fps > 0):
        raise RecordingError(f"--fps must be a positive number, got {args.fps}")
    if not (src.is_file() and src.suffix.lower() in CAMERA_FILE_SUFFIXES):
        if args.fps is None:
            raise RecordingError(f"{src}: the frame rate is not recorded in these files: give --fps")
        return args.fps

    header = open_camera_file(src).header
    base = header.time_base
    if args.fps is None:
        if base.fps is None:
            raise RecordingError(f"{src}: give --fps: {base.notes[0]}")
        return base.fps
    if not base.names_same_spacing(args.fps, header.n_frames):
        raise RecordingError(f"--fps {args.fps:g} but {src.name}'s saved frames come at "
                             f"{' or '.join(f'{r:.8g}' for r in base.readings_fps)} frames/s (its {base.source})")
    return args.fps


def _check_args(args: argparse.Namespace) -> None:
    for name in ("ball_diameter_mm", "gap_mm"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            raise RecordingError(f"--{name.replace('_', '-')} must be a positive number, got {v}")
    if args.gap_mm <= args.ball_diameter_mm:
        raise RecordingError(f"--gap-mm {args.gap_mm:g} must exceed --ball-diameter-mm {args.ball_diameter_mm:g}")
    if args.subset_px <= 0 or args.subset_px % 2 == 0:
        raise RecordingError(f"--subset-px must be a positive odd integer, got {args.subset_px}")
    if args.mesh_step_px <= 0:
        raise RecordingError(f"--mesh-step-px must be a positive integer, got {args.mesh_step_px}")
    tilt = getattr(args, "axis_tilt_deg", 0.0)
    if not (math.isfinite(tilt) and 0.0 <= tilt <= 90.0):
        raise RecordingError(f"--axis-tilt-deg (rig.yaml setup.axis_tilt_deg) must be in [0, 90] degrees from "
                             f"vertical (0 vertical, 90 horizontal), got {tilt:g}")


def read_first_frames(src: Path, fps: float, n: int = MAX_FRAMES_EXAMINED) -> tuple[list[tuple[int, np.ndarray]], int]:
    """(index, gray-level float image) of the first ``n`` readable frames, and the source's significant bits per
    pixel (what saturation is judged against); frame 0 must be readable."""
    from vibro_dic.init_rig import to_gray255

    seq = FrameSequence(src, CameraConfig(fps=fps, t0_s=0.0, mm_per_px=1.0))
    out = []
    for frame in seq:
        if frame.ok:
            out.append((frame.index, to_gray255(frame.image)))
        elif not out:
            raise RecordingError(f"{src}: the first frame is unreadable ({frame.error})")
        if len(out) >= n:
            break
    return out, seq.effective_bits


def rig_yaml_text(p, args: argparse.Namespace, fps: float, source: Path, frequency_hz: float, freq_note: str) -> str:
    """The commented rig.yaml for proposal ``p`` (:class:`vibro_dic.init_rig.Proposal`)."""
    b, pl, sc = p.ball, p.plates, p.scale
    a = ASSUMED
    if b.method == "outline":
        nl = "\n#         "
        ball_lines = f"""#   ball: plain (no speckle), tracked by its outline: centre ({b.x_px:.3f}, {b.y_px:.3f}) px, \
radius {b.radius_px:.3f} +- {b.fit_radius_std_px:.4f} px
#         (1 sigma from the residuals of a circle through {b.n_edge_points} of {b.n_sectors} outline sectors, \
{b.edge_residual_px:.3f} px RMS;
#         the scale takes +- {b.radius_std_px:.2f} px: an edge model's definition of the edge); moves
#         {p.motion.ball_relative_range_px:.1f} px relative to the plates; edge blur sigma {b.blur_px:.2f} px
#         outline check: {outline_summary(p.ball_outline, nl)}
"""
        ball_roi = f"{p.ball_roi.as_list()}    # box around the whole ball, >= {_margin(p):.1f} px beyond its outline"
        ball_cr = "structure"
    else:
        ball_lines = f"""#   ball: centre ({b.x_px:.2f}, {b.y_px:.2f}) px, radius {b.radius_px:.2f} +- \
{b.radius_std_px:.2f} px (1 sigma from the
#         scatter of {b.n_edge_points} sector edges, {b.edge_residual_px:.2f} px); moves \
{p.motion.ball_relative_range_px:.1f} px relative to the plates
"""
        ball_roi = f"{p.ball_roi.as_list()}    # square inside the ball, >= 6 px inside its edge"
        ball_cr = f"ball {p.ball_cramer_rao_px:.4f} px,\n#         structure"
    method = "\n  ball_method: outline    # a plain ball, tracked by its outline (docs/real-footage.md)" \
        if b.method == "outline" else ""
    tilt = float(getattr(args, "axis_tilt_deg", 0.0))
    tilt_note = ("--axis-tilt-deg" if tilt else "ASSUMED vertical: --axis-tilt-deg for a tilted or horizontal rig") + \
        "; gravity along the axis g cos(tilt)"
    return f"""# rig.yaml proposed by `vibro init` from {source}
# Measured on frame 0 ({p.width_px}x{p.height_px} px) and the motion over {p.motion.frames.size} frames:
{ball_lines.rstrip()}
#   plates: cavity edges at rows {pl.top_row_px:.2f} +- {pl.top_std_px:.2f} and \
{pl.bottom_row_px:.2f} +- {pl.bottom_std_px:.2f} (1 sigma from column blocks;
#         gap {pl.gap_px:.2f} +- {pl.gap_std_px:.2f} px); structure travel seen \
{p.motion.structure_range_px[0]:+.1f}..{p.motion.structure_range_px[1]:+.1f} px (rows, + down)
#   {"plate " if b.method == "outline" else ""}edges located on the texture along them, blur sigma \
{p.edge_sigma_px:.2f} px
#   scale from the ball ({args.ball_diameter_mm:g} mm): {sc.from_ball:.6f} mm/px +- {_pct(sc.ball_rel_std)} %
#   scale from the gap  ({args.gap_mm:g} mm): {sc.from_gap:.6f} mm/px +- {_pct(sc.gap_rel_std)} %
#   they disagree by {100 * sc.disagreement_rel:+.2f} % \
(allowed {100 * sc.tolerance_rel:.2f} %: 3 sigma + 0.25 px per edge)
#   scale written: their inverse-variance mean (ball weight {sc.ball_weight:.2f}), \
{sc.mm_per_px:.6f} mm/px +- {_pct(sc.rel_std)} %
#   image noise {p.noise_gray:.2f} gray levels; worst subset displacement std (Cramer-Rao): \
{ball_cr} {p.structure_cramer_rao_px:.4f} px
# Keys marked ASSUMED are not measurable from video: the paper's Test 1 rig; edit them for yours.
camera:
  fps: {fps!r}
  t0_s: 0.0
  mm_per_px: {sc.mm_per_px:.6g}    # ball and gap combined (see above)
  mm_per_px_rel_std: {sc.rel_std:.2g}    # its relative 1-sigma: a tilt within 3 of it is not claimed
setup:
  axis_tilt_deg: {tilt!r}    # the motion axis from vertical as mounted (0 vertical, 90 horizontal); {tilt_note}
ball:
  mass_kg: {a['ball_mass_kg']!r}    # ASSUMED
  diameter_mm: {args.ball_diameter_mm!r}
  youngs_modulus_pa: {a['ball_youngs_modulus_pa']!r}    # ASSUMED
  poisson_ratio: {a['ball_poisson_ratio']!r}    # ASSUMED
structure:
  gap_mm: {args.gap_mm!r}
  mass_kg: {a['structure_mass_kg']!r}    # ASSUMED
  youngs_modulus_pa: {a['structure_youngs_modulus_pa']!r}    # ASSUMED
  poisson_ratio: {a['structure_poisson_ratio']!r}    # ASSUMED
excitation:
  frequency_hz: {frequency_hz:.6g}    # {freq_note}; vibro analyze refines it
dic:
  subset_px: {p.subset_px}
  mesh_step_px: {p.mesh_step_px}{method}
  ball_roi: {ball_roi}
  structure_roi: {p.structure_roi.as_list()}    # on the {p.structure_plate} plate, in the image over the travel seen
"""


def _pct(rel: float) -> str:
    """A relative 1-sigma in percent, to two decimals or two significant digits when smaller."""
    pct = 100.0 * rel
    if not (math.isfinite(pct) and pct > 0):
        return f"{pct:.2f}"
    return f"{pct:.{max(2, 1 - math.floor(math.log10(pct)))}f}"


def _margin(p) -> float:
    """The least background (px) the outline box keeps beyond the ball's outline."""
    b, r = p.ball, p.ball_roi
    return min(b.x_px - r.x, r.x + r.w - 1 - b.x_px, b.y_px - r.y, r.y + r.h - 1 - b.y_px) - b.radius_px


def outline_summary(check, sep: str = " ") -> str:
    """The outline check's prediction (:class:`vibro_dic.outline.OutlineTexture`): sigma, contrast over noise,
    sectors; ``sep`` between the sigma and the rest."""
    s = check.mesh_sigma_px
    return (f"predicted displacement sigma {s[0]:.4f} px (x), {s[1]:.4f} px (y);{sep}contrast "
            f"{abs(check.contrast_gray):.1f} / noise {check.noise_gray:.2f} gray levels = "
            f"{abs(check.contrast_gray) / check.noise_gray:.0f}x, {check.n_usable} of {len(check.points)} "
            f"sectors usable (the tracker needs {check.min_usable})")


def draw_preview(frame0: np.ndarray, p, path: Path, scale_up: int = 2) -> None:
    """Frame 0 with the ball circle, plate edges, ROIs, mesh points and a scale bar, written to ``path``."""
    img = np.clip(frame0, 0, 255).astype(np.uint8)
    img = cv2.cvtColor(cv2.resize(img, None, fx=scale_up, fy=scale_up, interpolation=cv2.INTER_NEAREST),
                       cv2.COLOR_GRAY2BGR)
    s = scale_up
    b = p.ball
    cv2.circle(img, (int(round(b.x_px * s)), int(round(b.y_px * s))), int(round(b.radius_px * s)), (0, 200, 255), 1)
    for row in (p.plates.top_row_px, p.plates.bottom_row_px):
        cv2.line(img, (0, int(round(row * s))), (img.shape[1] - 1, int(round(row * s))), (255, 128, 0), 1)
    for roi, colour in ((p.ball_roi, (0, 255, 0)), (p.structure_roi, (255, 0, 255))):
        cv2.rectangle(img, (roi.x * s, roi.y * s), ((roi.x + roi.w) * s - 1, (roi.y + roi.h) * s - 1), colour, 1)
        if roi is p.ball_roi and b.method == "outline":
            continue  # a box around the whole ball: no subsets
        for x, y in mesh_points(roi, p.subset_px, p.mesh_step_px):
            cv2.circle(img, (int(round(x * s)), int(round(y * s))), 2, colour, -1)
    bar_mm = 1.0 if p.width_px * p.scale.mm_per_px > 2.0 else 0.5
    bar_px = bar_mm / p.scale.mm_per_px * s
    y = img.shape[0] - 12
    cv2.line(img, (8, y), (8 + int(round(bar_px)), y), (255, 255, 255), 3)
    cv2.putText(img, f"{bar_mm:g} mm", (8, y - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), img):
            raise RecordingError(f"{path}: cannot write the preview PNG")


def run(args: argparse.Namespace) -> int:
    from vibro_dic.init_rig import propose

    _check_args(args)
    source = Path(args.source)
    src = _frames_source(source)
    out = Path(args.out) if args.out else _recording_dir(source) / "rig.yaml"
    preview = out.with_name(out.stem + "_preview.png")
    accel = choose_accel(_recording_dir(source), AccelRequest(file=args.accel, upper=args.accel_upper,
                                                              lower=args.accel_lower, none=args.no_accel))
    prepare_output_file(out, overwrite=args.overwrite)
    prepare_output_file(preview, overwrite=args.overwrite)
    fps = _fps(args, src)
    frames, effective_bits = read_first_frames(src, fps)
    p = propose(frames, ball_diameter_mm=args.ball_diameter_mm, gap_mm=args.gap_mm, fps=fps,
                subset_px=args.subset_px, mesh_step_px=args.mesh_step_px, effective_bits=effective_bits)
    if args.frequency_hz is not None:
        freq, note = args.frequency_hz, "given by --frequency-hz"
    elif p.frequency_hz is not None:
        freq, note = p.frequency_hz, "estimated: " + p.frequency_note
    else:
        raise RecordingError(f"{src}: cannot estimate the shaker frequency ({p.frequency_note}): give --frequency-hz")
    text = rig_yaml_text(p, args, fps, source, freq, note) + ("" if accel is None else "\n" + accel.yaml())
    import yaml


    rig = parse_rig(yaml.load(text, Loader=_RigLoader), str(out))  # what we write must load as it will be read
    check_rois_in_image(rig, p.height_px, p.width_px)
    atomic_write_text(out, text)
    draw_preview(frames[0][1], p, preview)
    sc = p.scale
    print(f"wrote {out} and {preview}")
    print(f"scale {sc.mm_per_px:.6f} mm/px +- {_pct(sc.rel_std)} %: {sc.from_ball:.6f} from the ball (r "
          f"{p.ball.radius_px:.2f} +- {p.ball.radius_std_px:.2f} px), {sc.from_gap:.6f} from the gap "
          f"({p.plates.gap_px:.2f} +- {p.plates.gap_std_px:.2f} px), {100 * sc.disagreement_rel:+.2f} % apart "
          f"(allowed {100 * sc.tolerance_rel:.2f} %)")
    if p.ball.method == "outline":
        print(f"ball: plain, tracked by its outline (dic.ball_method outline): {outline_summary(p.ball_outline)}")
    print(f"ball_roi {p.ball_roi.as_list()}  structure_roi {p.structure_roi.as_list()}  frequency {freq:.4g} Hz")
    print(_accel_line(accel, args.no_accel))
    return 0


def _accel_line(accel: AccelChoice | None, asked_none: bool) -> str:
    """What init did about the accelerometers, in one line."""
    if accel is not None:
        return f"accelerometers: {accel.file} ({', '.join(accel.lines[1:])})"
    if asked_none:
        return "accelerometers: none (--no-accel): video only"
    return "accelerometers: no accel.csv or *.tdms beside the video: video only"
