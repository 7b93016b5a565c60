"""COR statistics: mean/std per plate (Table 2), histogram and normal Q-Q (Fig. 15-16), error bars (Fig. 14)."""

from __future__ import annotations

from vibro_model.results import CorSummary
from vibro_model.statistics import NormalCheck, filliben_medians, normal_check

__all__ = ["NormalCheck", "cor_summary", "errorbar_table", "filliben_medians", "normal_check"]


def cor_summary(impacts) -> dict[str, dict]:
    """{"top": {"mean", "std", "n"}, "bottom": {...}}: sample mean and std (ddof=1) of the COR per plate.

    mean is None when n = 0 and std is None when n < 2 (JSON null: undefined, not zero). The one
    definition is :class:`vibro_model.results.CorSummary`.
    """
    return CorSummary.of(impacts).to_dict()


def errorbar_table(summaries: dict[str, dict]) -> list[dict]:
    """Rows for Fig. 14 from {label: cor_summary}: label, plate, mean, std, n (plates with n = 0 skipped)."""
    rows = []
    for label, summ in summaries.items():
        for plate in ("bottom", "top"):
            s = summ.get(plate) or {}
            if s.get("n"):
                rows.append({"label": label, "plate": plate, "mean": s["mean"], "std": s["std"], "n": s["n"]})
    return rows
