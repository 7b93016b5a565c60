"""Impacts of a synthetic rig's truth file (``vibro synth``'s ``<rec>.truth.json``) that a recording can measure."""

from __future__ import annotations


def measurable_impacts(truth: dict) -> list[dict]:
    """The truth's impacts whose flights before and after lie inside the recording (Eq. 15 needs both)."""
    t0, t1 = truth["frames"]["t_s"][0], truth["frames"]["t_s"][-1]
    flights = truth["flights"]
    out = []
    for imp in truth["impacts"]:
        before = [f for f in flights if abs(f["t_end"] - imp["t"]) < 1e-9]
        after = [f for f in flights if abs(f["t_start"] - imp["t"]) < 1e-9]
        if before and after and before[0]["t_start"] >= t0 and after[0]["t_end"] <= t1:
            out.append(imp)
    return out
