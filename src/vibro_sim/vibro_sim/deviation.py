"""Deviation D between a simulated and a measured trajectory (paper Eq. 18)."""

from __future__ import annotations

import numpy as np


def deviation(t_s, y_sim, y_exp) -> float:
    """D = sqrt( int (y_sim - y_exp)^2 dt / int y_exp^2 dt ), trapezoidal integrals over t_s.

    A fraction (0.03 = 3 %). Any consistent length unit. NaN samples are dropped.
    Raises ValueError for mismatched lengths, fewer than 2 samples, non-increasing
    times, or a measured trajectory that is zero everywhere.
    """
    t = np.asarray(t_s, dtype=float).ravel()
    ys = np.asarray(y_sim, dtype=float).ravel()
    ye = np.asarray(y_exp, dtype=float).ravel()
    if not (t.size == ys.size == ye.size):
        raise ValueError(f"deviation: lengths differ (t {t.size}, y_sim {ys.size}, y_exp {ye.size})")
    keep = np.isfinite(t) & np.isfinite(ys) & np.isfinite(ye)
    t, ys, ye = t[keep], ys[keep], ye[keep]
    if t.size < 2:
        raise ValueError("deviation: need at least 2 finite samples")
    if np.any(np.diff(t) <= 0):
        raise ValueError("deviation: times must increase")
    den = np.trapezoid(ye ** 2, t)
    if den <= 0:
        raise ValueError("deviation: the measured trajectory is zero everywhere (D undefined)")
    return float(np.sqrt(np.trapezoid((ys - ye) ** 2, t) / den))
