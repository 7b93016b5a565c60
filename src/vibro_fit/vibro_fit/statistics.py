"""COR statistics: mean/std per plate (Table 2), histogram and normal Q-Q (Fig. 15-16), error bars (Fig. 14)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vibro_model.results import CorSummary


def cor_summary(impacts) -> dict[str, dict]:
    """{"top": {"mean", "std", "n"}, "bottom": {...}}: sample mean and std (ddof=1) of the COR per plate.

    mean is None when n = 0 and std is None when n < 2 (JSON null: undefined, not zero). The one
    definition is :class:`vibro_model.results.CorSummary`.
    """
    return CorSummary.of(impacts).to_dict()


@dataclass
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


def normal_check(values, bins: int | str = "auto") -> NormalCheck:
    """Histogram + normal Q-Q (scipy.stats.probplot, Filliben plotting positions) of ``values`` (n >= 3)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size < 3:
        raise ValueError(f"normal check needs at least 3 values, got {v.size}")
    counts, edges = np.histogram(v, bins=bins)
    from scipy import stats  # here, not at import (node start-up time)

    (osm, osr), (slope, intercept, r) = stats.probplot(v, dist="norm")
    return NormalCheck(counts, edges, float(v.mean()), float(v.std(ddof=1)), np.asarray(osm), np.asarray(osr),
                       float(slope), float(intercept), float(r))


def errorbar_table(summaries: dict[str, dict]) -> list[dict]:
    """Rows for Fig. 14 from {label: cor_summary}: label, plate, mean, std, n (plates with n = 0 skipped)."""
    rows = []
    for label, summ in summaries.items():
        for plate in ("bottom", "top"):
            s = summ.get(plate) or {}
            if s.get("n"):
                rows.append({"label": label, "plate": plate, "mean": s["mean"], "std": s["std"], "n": s["n"]})
    return rows
