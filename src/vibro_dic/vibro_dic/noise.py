"""Displacement noise of a motionless recording (paper section 5, Fig. 17).

The measured displacement of a still rig is pure error. It is split into
- a **low-frequency** part: zero-phase 4th-order Butterworth low-pass (``sosfiltfilt``)
  at ``split_hz`` (default 50 Hz): slow drift, camera or stand motion, lighting drift;
- a **high-frequency** part: the rest, image noise propagated through the correlation.

The study only means something on a recording that does not move: :func:`check_still` refuses one whose
displacement spread (1st..99th percentile range) of either body exceeds ``MAX_STILL_SPREAD_PX`` (3 px):
that is hundreds of times the DIC noise (~0.005 px per mesh at 2 gray levels of image noise) and beyond
the sub-pixel drift of a camera stand the low-frequency part is meant to measure, while the motion of a
running absorber is millimetres (tens of pixels).

Why 50 Hz by default: the paper attributes the slow part to unwanted camera motion;
camera stands and building floors have their modes well below 50 Hz, while image noise
is white and spreads evenly up to fps/2 (500 Hz at 1000 fps), so 90 % of its power lies
above the split. Change it with ``split_hz`` (must be below fps/2).
"""

from __future__ import annotations

import math

import numpy as np

from vibro_io.dictrack import DicTrack
from vibro_model.errors import RecordingError

DEFAULT_SPLIT_HZ = 50.0
_MIN_FRAMES = 32
MAX_STILL_SPREAD_PX = 3.0


def high_frequency_sigma_mm(x_mm: np.ndarray) -> float:
    """White-noise sigma (mm) of a series: the smallest over the orders k = 2, 3, 4 of the robust std
    (1.4826 MAD) of its k-th differences divided by sqrt(C(2k, k)) (their std for white noise). Higher
    orders suppress a smooth motion (a 22 Hz sine at 1000 fps loses (2 pi 22 / 1000)^k of its amplitude);
    NaN samples drop the differences they touch."""
    x = np.asarray(x_mm, dtype=float)
    best = float("nan")
    for k in (2, 3, 4):
        d = np.diff(x, n=k)
        d = d[np.isfinite(d)]
        if d.size < 3:
            continue
        s = float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(math.comb(2 * k, k)))
        best = s if not np.isfinite(best) else min(best, s)
    return best


def check_still(track: DicTrack, mm_per_px: float, max_spread_px: float = MAX_STILL_SPREAD_PX) -> None:
    """Raise RecordingError naming the measured motion when the ball or the structure moves: spread (1st..99th
    percentile range) above ``max_spread_px`` (see module docstring)."""
    moving = []
    for body in ("ball", "structure"):
        x = np.where(track.lost, np.nan, getattr(track, f"{body}_mm"))
        x_ok = x[np.isfinite(x)]
        if x_ok.size < _MIN_FRAMES:
            continue
        lo, hi = np.percentile(x_ok, [1, 99])
        spread_mm = float(hi - lo)
        if spread_mm > max_spread_px * mm_per_px:
            sigma = high_frequency_sigma_mm(x)
            moving.append(f"the {body} moves {spread_mm:.4f} mm ({spread_mm / mm_per_px:.1f} px, 1st..99th "
                          f"percentile range), {spread_mm / sigma:.0f} x its DIC noise of {sigma:.2e} mm")
    if moving:
        raise RecordingError("noise study of a moving recording refused: " + "; ".join(moving)
                             + f" (more than {max_spread_px:g} px): the displacement is motion, not noise; "
                             "record the rig with the shaker off")


def split_noise(x_mm: np.ndarray, fps: float, split_hz: float = DEFAULT_SPLIT_HZ) -> dict[str, float]:
    """Noise statistics (mm) of one displacement series sampled at ``fps`` (NaN = lost frame).

    Lost frames are left out of the statistics and bridged by linear interpolation for
    the filter. Returns std_mm, high_std_mm, low_std_mm, peak_to_peak_mm, mean_mm, n_used.
    """
    x = np.asarray(x_mm, dtype=float)
    good = np.isfinite(x)
    if good.sum() < _MIN_FRAMES:
        raise RecordingError(f"noise study needs at least {_MIN_FRAMES} tracked frames, got {int(good.sum())}")
    if not 0.0 < split_hz < 0.5 * fps:
        raise RecordingError(f"noise split frequency must be in (0, fps/2 = {0.5 * fps:g}) Hz, got {split_hz:g}")
    k = np.arange(x.size)
    filled = np.interp(k, k[good], x[good])
    centred = filled - filled[good].mean()
    from scipy.signal import butter, sosfiltfilt  # here, not at import: scipy.signal costs ~1.7 s CPU

    sos = butter(4, split_hz, btype="lowpass", fs=fps, output="sos")
    low = sosfiltfilt(sos, centred)
    high = centred - low
    return {
        "std_mm": float(np.std(centred[good])),
        "high_std_mm": float(np.std(high[good])),
        "low_std_mm": float(np.std(low[good])),
        "peak_to_peak_mm": float(np.ptp(centred[good])),
        "mean_mm": float(filled[good].mean()),
        "n_used": int(good.sum()),
    }


def noise_study(track: DicTrack, fps: float, mm_per_px: float, split_hz: float = DEFAULT_SPLIT_HZ) -> dict:
    """Noise study of a motionless recording's track: per body (ball, structure) the split in mm and px.
    Raises RecordingError when the recording moves (:func:`check_still`).

    Returns {"split_hz", "fps", "n_frames", "n_lost", "ball": {...}, "structure": {...}} where each
    body holds std/high_std/low_std/peak_to_peak in mm and px (see :func:`split_noise`).
    """
    check_still(track, mm_per_px)
    out: dict = {"split_hz": float(split_hz), "fps": float(fps), "n_frames": len(track),
                 "n_lost": int(np.count_nonzero(track.lost))}
    for body in ("ball", "structure"):
        x = np.where(track.lost, np.nan, getattr(track, f"{body}_mm"))
        stats = split_noise(x, fps, split_hz)
        for key in ("std", "high_std", "low_std", "peak_to_peak"):
            stats[f"{key}_px"] = stats[f"{key}_mm"] / mm_per_px
        out[body] = stats
    return out


def cramer_rao_px(grad_sq_sum: float | np.ndarray, noise_sigma: float) -> float | np.ndarray:
    """Cramer-Rao-type bound of one subset's displacement std (px) along an axis.

    sigma_u ~ sqrt(2) sigma_noise / sqrt(sum over the subset of the squared intensity
    gradient along that axis); sqrt(2) because both the reference and the current image
    carry noise of std ``noise_sigma`` (gray levels).
    """
    return math.sqrt(2.0) * noise_sigma / np.sqrt(grad_sq_sum)
