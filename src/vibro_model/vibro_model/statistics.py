"""Histogram and normal Q-Q check of a sample (the COR statistics of results.json, paper Fig. 15-16).

numpy only at import; :func:`normal_check` takes the normal quantiles from ``scipy.special.ndtri`` when called.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(kw_only=True)
class NormalCheck:
    """Histogram and normal Q-Q diagram of a sample."""

    counts: np.ndarray
    edges: np.ndarray
    mean: float
    std: float
    theoretical_quantiles: np.ndarray
    ordered_values: np.ndarray
    slope: float
    intercept: float
    r: float  # correlation coefficient of the Q-Q points (1 = perfectly normal)


def filliben_medians(n: int) -> np.ndarray:
    """Medians of the n uniform order statistics, Filliben's (1975) approximation (as scipy.stats.probplot)."""
    v = np.empty(n)
    v[-1] = 0.5 ** (1.0 / n)
    v[0] = 1.0 - v[-1]
    v[1:-1] = (np.arange(2, n) - 0.3175) / (n + 0.365)
    return v


def normal_check(values, bins: int | str = "auto") -> NormalCheck:
    """Histogram + normal Q-Q of ``values`` (n >= 3): theoretical quantiles at Filliben's plotting positions,
    a least-squares line through the Q-Q points and their correlation r, the numbers scipy.stats.probplot gives
    (computed with scipy.special.ndtri: importing scipy.stats costs ~1.5 s of CPU in every process)."""
    from scipy.special import ndtri

    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size < 3:
        raise ValueError(f"normal check needs at least 3 values, got {v.size}")
    counts, edges = np.histogram(v, bins=bins)
    osm = ndtri(filliben_medians(v.size))
    osr = np.sort(v)
    dm, dr = osm - osm.mean(), osr - osr.mean()
    sxx, syy, sxy = float(dm @ dm), float(dr @ dr), float(dm @ dr)
    slope = sxy / sxx
    intercept = float(osr.mean() - slope * osm.mean())
    r = sxy / np.sqrt(sxx * syy) if syy > 0 else float("nan")  # undefined for a constant sample
    return NormalCheck(counts=counts, edges=edges, mean=float(v.mean()), std=float(v.std(ddof=1)),
                       theoretical_quantiles=osm, ordered_values=osr,
                       slope=float(slope), intercept=intercept, r=float(r))
