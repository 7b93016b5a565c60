"""Segmentation of the ball track into free flights.

Rule (documented, used by both :func:`vibro_fit.identify.identify` and the streaming fitter):

An impact is a kink of the relative motion y_rel = ball - structure (a jump of the relative velocity
at an extreme of y_rel). The structure's motion is smooth (a sine), so that kink is a kink of the ball
track itself, which is cheaper to test frame by frame and does not need the structure fit:

1. For every good frame j with good neighbours i < j < k, the ball acceleration is estimated from the
   second divided difference acc_j = 2 [ (y_k - y_j)/(t_k - t_j) - (y_j - y_i)/(t_j - t_i) ] / (t_k - t_i).
   In free flight acc_j = -g_axis + F/m (a few % of g), g_axis = g cos(theta) the gravity along the motion axis
   (rig.yaml ``setup.axis_tilt_deg`` theta: g vertical, 0 horizontal). An impact between frames k and k+1 makes the
   estimates at k and k+1 jump by about dv/dt_frame (hundreds of m/s^2).
2. Frame j is a *contact frame* when |acc_j + g_axis| > max(k_sigma * sigma_acc_j, min_threshold_mps2), with
   sigma_acc_j the noise of that estimate from the position noise sigma (itself from the median absolute
   deviation of the second differences of the whole track, or of a warm-up window when streaming).
   Frames next to an accelerometer impact time (the last before and the first after) are contact frames
   too.
3. Consecutive contact frames form a cluster. A cluster of at most ``max_impact_frames`` frames is an
   impact (normally exactly the 2 frames next to the impact instant, which are excluded from the fits:
   they are the frames whose exposure can overlap the contact and the blur); a longer cluster is a
   contact phase (ball resting on or carried by a plate).
4. The runs of frames between clusters are the flights. A flight with fewer than ``min_points`` frames is
   reported, not fitted. A fitted flight is *free* when its parabola residual RMS is at most
   ``rms_factor * sigma + rms_floor_mm`` and |2a + g_axis| <= ``max_friction_g * g`` (a force in flight of at
   most that fraction of the ball's weight m g, whatever the orientation); no COR is published from a flight
   that is not free. On a horizontal axis a free flight is a straight line (plus the guide rods' friction) and
   an impact a kink where the velocity reverses: the same rule with g_axis = 0.
5. Two flights whose parabolas do not reverse the relative velocity were split by a spurious cluster
   (an outlier frame): they are merged and refitted.

Defaults (:class:`SegmentationConfig`): k_sigma 6, min_threshold 3 m/s^2, max_impact_frames 4,
min_points 6, rms_factor 3, rms_floor 0.002 mm, max_friction 0.5 g, g_axis = 9.81 m/s^2 (vertical);
:func:`segmentation_config` sets g_axis from the rig (the one place the identification's config meets rig.yaml).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from vibro_model.constants import G_MPS2
from vibro_model.units import m_to_mm, mm_to_m


@dataclass(frozen=True, kw_only=True)
class SegmentationConfig:
    """Parameters of the segmentation rule (see module docstring)."""

    k_sigma: float = 6.0
    min_threshold_mps2: float = 3.0
    max_impact_frames: int = 4
    min_points: int = 6
    rms_factor: float = 3.0
    rms_floor_mm: float = 0.002
    max_friction_g: float = 0.5
    #: gravity along the motion axis (m/s^2): what a free flight falls at, g cos(setup.axis_tilt_deg)
    g_mps2: float = G_MPS2


def segmentation_config(rig, base: SegmentationConfig | None = None) -> SegmentationConfig:
    """The segmentation's config for ``rig`` (a :class:`vibro_io.rig.RigConfig`): ``base`` (default: the
    defaults) with the gravity along the motion axis as mounted, g cos(setup.axis_tilt_deg)."""
    return replace(base or SegmentationConfig(), g_mps2=float(rig.g_axis_mps2))


def noise_sigma_mm(t_s: np.ndarray, y_mm: np.ndarray, g_mps2: float = G_MPS2) -> float:
    """Position noise sigma (mm) of a track from the MAD of its second differences (uniform steps only).

    For white noise of std sigma, a second difference has std sqrt(6) sigma; MAD * 1.4826 estimates the
    std robustly (impacts are a minority of frames). ``g_mps2``: the free flights' fall along the axis (m/s^2).
    """
    t_s = np.asarray(t_s, float)
    y_mm = np.asarray(y_mm, float)
    ok = np.isfinite(y_mm)
    idx = np.flatnonzero(ok)
    if idx.size < 5:
        return float("nan")
    dt = float(np.median(np.diff(t_s)))
    consec = (idx[2:] - idx[:-2]) == 2
    d2 = y_mm[idx[2:]] - 2 * y_mm[idx[1:-1]] + y_mm[idx[:-2]]
    d2 = d2[consec]
    if d2.size < 3:
        return float("nan")
    # remove the free-flight gravity term before the MAD
    d2 = d2 + m_to_mm(g_mps2) * dt * dt
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / np.sqrt(6.0)


#: order of the differences :func:`difference_noise_mm` takes: a 22 Hz drive filmed at 1000 fps leaves
#: A (w dt)^6 ~ 1e-5 mm in a 6th difference, against sqrt(924) ~ 30 sigma of noise there
NOISE_DIFFERENCE_ORDER = 6


def difference_noise_mm(y_mm: np.ndarray, frame: np.ndarray, order: int = NOISE_DIFFERENCE_ORDER) -> float:
    """White-noise sigma (mm) of a smooth track (``y_mm`` at frame numbers ``frame``, NaN where not measured) from
    the median |k-th difference| over runs of consecutive frames: for white noise a k-th difference has std
    sqrt(C(2k, k)) sigma, and a motion much slower than the frame rate leaves almost nothing in it. Unlike the
    residual of one sine over the take, a drive whose amplitude or frequency moved is not taken for noise; the
    median resists impacts and outliers. NaN with fewer than 10 differences."""
    y = np.asarray(y_mm, float)
    frame = np.asarray(frame)
    ok = np.flatnonzero(np.isfinite(y))
    if ok.size <= order + 10:
        return float("nan")
    consecutive = (frame[ok[order:]] - frame[ok[:-order]]) == order
    d = np.diff(y[ok], order)[consecutive]
    if d.size < 10:
        return float("nan")
    return float(np.median(np.abs(d)) / (0.6744897501960817 * math.sqrt(math.comb(2 * order, order))))


def accel_estimate(t3: np.ndarray, y3_mm: np.ndarray) -> tuple[float, float]:
    """Ball acceleration (m/s^2) at the middle of three samples, and the factor f such that the estimate's
    noise std is f * sigma_mm (sigma in mm)."""
    h1 = t3[1] - t3[0]
    h2 = t3[2] - t3[1]
    acc = 2.0 * ((y3_mm[2] - y3_mm[1]) / h2 - (y3_mm[1] - y3_mm[0]) / h1) / (h1 + h2)
    fac = 2.0 / (h1 + h2) * np.sqrt(1 / h2 ** 2 + (1 / h1 + 1 / h2) ** 2 + 1 / h1 ** 2)
    return mm_to_m(acc), mm_to_m(fac)


def plate_levels(impacts, free_play_mm: float | None = None) -> dict[str, float]:
    """Relative position (ball - structure, mm, track coordinates) of each plate: median over the impacts.

    DIC gives displacements only, so the track's ball - structure differs from the ball centre minus the
    cavity centre by the constant c0 (their offset at frame 0). The ball centre is at +b at the top plate
    and -b at the bottom one, so y_top = b - c0 and y_bottom = -b - c0. Returns "top"/"bottom" for the
    plates that have impacts, ``offset_mm`` = c0 (both plates: -(y_top + y_bottom)/2, independent of b;
    one plate: from the rig's ``free_play_mm``) and, with both plates, the measured free play
    ``free_play_mm`` = (y_top - y_bottom)/2.
    """
    out: dict[str, float] = {}
    for plate in ("top", "bottom"):
        vals = [i.y_rel_mm for i in impacts if i.plate == plate]
        if vals:
            out[plate] = float(np.median(vals))
    if "top" in out and "bottom" in out:
        out["offset_mm"] = -0.5 * (out["top"] + out["bottom"])
        out["free_play_mm"] = 0.5 * (out["top"] - out["bottom"])
    elif free_play_mm is not None and "top" in out:
        out["offset_mm"] = free_play_mm - out["top"]
    elif free_play_mm is not None and "bottom" in out:
        out["offset_mm"] = -free_play_mm - out["bottom"]
    return out
