"""Mesh of DIC points inside a region of interest.

Pixel convention: x = column, y = row (rows grow downward). A point (x, y) is the
centre pixel of a square subset of side ``subset_px`` (odd), which covers columns
x - h .. x + h and rows y - h .. y + h with h = subset_px // 2.
"""

from __future__ import annotations

import numpy as np

from vibro_io.rig import Roi
from vibro_model.errors import RecordingError


def _axis_centres(start: int, length: int, subset_px: int, step_px: int) -> np.ndarray:
    """Centres along one axis such that every subset fits in [start, start + length); centred in the ROI."""
    half = subset_px // 2
    span = length - subset_px  # room for the centre to move, >= 0
    n = span // step_px + 1
    used = (n - 1) * step_px
    first = start + half + (span - used) // 2
    return first + step_px * np.arange(n)


def mesh_points(roi: Roi, subset_px: int, step_px: int) -> np.ndarray:
    """(N, 2) float array of (x, y) subset centres (pixels) on a grid of pitch ``step_px``.

    Every subset lies entirely inside ``roi``; the grid is centred in the ROI.
    Raises :class:`RecordingError` if the ROI cannot hold one subset or the
    parameters are not positive (subset_px must be odd).
    """
    if subset_px <= 0 or subset_px % 2 == 0:
        raise RecordingError(f"dic.subset_px must be a positive odd integer, got {subset_px}")
    if step_px <= 0:
        raise RecordingError(f"dic.mesh_step_px must be a positive integer, got {step_px}")
    if roi.w < subset_px or roi.h < subset_px:
        raise RecordingError(
            f"ROI {roi.as_list()} (x, y, w, h) is smaller than one {subset_px} px subset"
        )
    xs = _axis_centres(roi.x, roi.w, subset_px, step_px)
    ys = _axis_centres(roi.y, roi.h, subset_px, step_px)
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()]).astype(float)
