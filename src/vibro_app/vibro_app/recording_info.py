"""What a recording or a camera file holds, as one plain dict (``vibro info`` prints it, ``--json`` dumps it).

Keys (units in the names; None where the file does not say): ``source``, ``kind``, ``frames``
(frame slots, dropped ones included), ``images`` (in the file), ``dropped_frames``, ``width_px``,
``height_px``, ``fps`` and ``fps_source`` ("rig.yaml", "header", "header save step", "time stamps",
"header (contradictory)"), ``record_fps`` and ``save_step`` (the header's), ``fps_candidates`` (when
the header contradicts itself), ``t0_s`` (frame 0 relative to the trigger), ``start_time_unix_s``
and ``start_time_utc``, ``duration_s`` (frames / fps), ``time_base_notes``, ``bit_depth``
({container, effective}), ``frame0_gray`` ({min, max, mean, saturated_share}, in gray levels of the
file's effective depth), ``noise_gray`` ({sigma, method}, same scale), ``dic_sigma_px`` (predicted
DIC std per body from the ROIs, recordings only) and ``accelerometers`` ({rate_hz, unit, samples,
t_start_s, t_end_s, overlap_s}).
"""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path
from typing import Any

import numpy as np

from vibro_dic.texture import estimate_noise, mesh_corners
from vibro_io.camera_files import CAMERA_FILE_SUFFIXES
from vibro_io.frames import FrameSequence
from vibro_io.recording import open_recording
from vibro_io.rig import CameraConfig, load_yaml
from vibro_model.errors import RecordingError

#: Frame 1 is compared with frame 0 for the noise; a file of one frame uses the single-image estimate.
NOISE_PAIR = (0, 1)


def describe(path: str | Path) -> dict[str, Any]:
    """The info dict of a recording directory or of a camera file on its own (no rig.yaml needed)."""
    path = Path(path)
    if path.is_file() and path.suffix.lower() in CAMERA_FILE_SUFFIXES:
        return _describe_camera_file(path)
    if path.is_file():
        raise RecordingError(f"{path}: not a recording directory nor a camera file ({', '.join(CAMERA_FILE_SUFFIXES)})")
    return _describe_recording(path)


def _describe_camera_file(path: Path) -> dict[str, Any]:
    # no rig.yaml: the clock below only lets the frames be read (pixels); the times reported are the header's
    frames = FrameSequence(path, CameraConfig(fps=1.0, t0_s=0.0, mm_per_px=1.0))
    base = frames.camera_file.header.time_base
    out = _header_part(frames)
    out.update(fps=base.fps, fps_source=base.source)
    out["duration_s"] = None if base.fps is None else len(frames) / base.fps
    out.update(_pixels_part(frames, _first_images(frames, 2)))
    return out


def _header_part(frames: FrameSequence) -> dict[str, Any]:
    header = frames.camera_file.header
    base, start = header.time_base, header.start_time_unix_s
    return {
        "source": str(frames.source), "kind": _kind(frames),
        "frames": len(frames), "images": header.n_frames, "dropped_frames": base.dropped_slots,
        "unreadable_images": list(base.corrupt),
        "width_px": header.width_px, "height_px": header.height_px,
        "record_fps": base.record_fps, "save_step": base.step,
        "fps_candidates": list(base.candidates_fps) or None,
        "t0_s": base.t0_s, "start_time_unix_s": start, "start_time_utc": _utc(start),
        "time_base_notes": list(base.notes),
        "time_stamp_jitter_s": base.jitter_s,
    }


def _describe_recording(path: Path) -> dict[str, Any]:
    rec = open_recording(path)
    rig, frames = rec.rig, rec.frames
    raw = load_yaml(path / "rig.yaml")
    camera_keys = raw.get("camera") if isinstance(raw, dict) else None
    rig_gave_fps = isinstance(camera_keys, dict) and camera_keys.get("fps") is not None
    out: dict[str, Any] = {"source": str(frames.source), "kind": _kind(frames)}
    if frames.camera_file is not None:
        out.update(_header_part(frames))
        out["fps_source"] = "rig.yaml" if rig_gave_fps else frames.camera_file.header.time_base.source
    else:
        out.update(frames=len(frames), images=None, dropped_frames=None, width_px=frames.shape[1],
                   height_px=frames.shape[0], fps_source="rig.yaml")
        out.update(t0_s=rig.camera.t0_s, start_time_unix_s=rig.camera.start_time_unix_s,
                   start_time_utc=_utc(rig.camera.start_time_unix_s))
    out["fps"] = rig.camera.fps
    out["t0_s"] = rig.camera.t0_s
    out["duration_s"] = len(frames) / rig.camera.fps
    images = _first_images(frames, 2)
    out.update(_pixels_part(frames, images, rig.dic))
    out["dic_sigma_px"] = _dic_sigma(frames, images[0], rig, out["noise_gray"])
    out["rig"] = {"mm_per_px": rig.camera.mm_per_px, "ball_diameter_mm": rig.ball.diameter_mm,
                  "ball_mass_kg": rig.ball.mass_kg, "gap_mm": rig.structure.gap_mm,
                  "free_play_mm": rig.free_play_mm, "excitation_hz": rig.excitation.frequency_hz,
                  "axis_tilt_deg": rig.setup.axis_tilt_deg, "axis_gravity_mps2": rig.g_axis_mps2}
    out["accelerometers"] = _accel_part(rec, out["t0_s"], out["duration_s"])
    return out


def _kind(frames: FrameSequence) -> str:
    if frames.source.is_dir():
        return "frames folder"
    if frames.codec:
        return f"video ({frames.codec})"
    return "Photron MRAW" if frames.source.suffix.lower() in (".cih", ".cihx") else "Phantom CINE"


def _first_images(frames: FrameSequence, count: int) -> list[np.ndarray]:
    images = []
    for frame in frames.iter_slots(0, None):
        if frame.ok:
            images.append(frame.image)
        if len(images) == count:
            break
    if not images:
        raise RecordingError(f"{frames.source}: no readable frame")
    return images


def _pixels_part(frames: FrameSequence, images: list[np.ndarray], dic: Any = None) -> dict[str, Any]:
    """Bit depths, frame 0's gray levels and the noise (the texture check's estimate: frame difference, or the
    subsets' correlation for a lossy codec; never below quantization), in gray levels of the effective depth.
    ``images``: the first one or two readable frames; ``dic`` (rig.yaml's DicConfig, or None): the subsets the
    correlation estimate uses."""
    bits = frames.effective_bits
    shift = 0 if frames.dtype == np.uint8 else 16 - bits
    top = 2 ** bits - 1
    first = np.right_shift(images[0], shift)
    noise = estimate_noise(images[0], images[1] if len(images) == 2 else None, effective_bits=bits,
                           codec=frames.codec, corners=None if dic is None else mesh_corners(dic))
    return {
        "bit_depth": {"container": 8 * frames.dtype.itemsize, "effective": bits},
        "frame0_gray": {"min": int(first.min()), "max": int(first.max()), "mean": float(first.mean()),
                        "saturated_share": float(np.mean(first >= top)), "full_scale": top},
        "noise_gray": {"sigma": noise.sigma_gray / 2 ** shift, "method": noise.method},
    }


def _dic_sigma(frames: FrameSequence, image: np.ndarray, rig: Any, noise: dict[str, Any]) -> dict[str, float]:
    """Predicted DIC std (px) of the worst subset of each body's mesh in ``image`` (frame 0; Cramer-Rao bound)."""
    from vibro_dic.init_rig import worst_cramer_rao_px

    scale = 1 if frames.dtype == np.uint8 else 2 ** (16 - frames.effective_bits)
    sigma = noise["sigma"] * scale
    out = {}
    for body, roi in (("ball", rig.dic.ball_roi), ("structure", rig.dic.structure_roi)):
        out[body] = worst_cramer_rao_px(image.astype(np.float64), roi, rig.dic.subset_px, rig.dic.mesh_step_px, sigma)
    return out


def _accel_part(rec: Any, t0_s: float, duration_s: float) -> dict[str, Any] | None:
    accel = rec.load_accel()
    if accel is None:
        return None
    t = accel.t_s
    lo, hi = max(float(t[0]), t0_s), min(float(t[-1]), t0_s + duration_s)
    return {"rate_hz": float(accel.sample_rate_hz), "unit": getattr(accel, "source_unit", "m/s^2"),
            "samples": int(len(t)), "t_start_s": float(t[0]), "t_end_s": float(t[-1]),
            "overlap_s": max(0.0, hi - lo)}


def _utc(unix_s: float | None) -> str | None:
    if unix_s is None or not math.isfinite(unix_s):
        return None
    return dt.datetime.fromtimestamp(unix_s, tz=dt.timezone.utc).isoformat(timespec="microseconds")
