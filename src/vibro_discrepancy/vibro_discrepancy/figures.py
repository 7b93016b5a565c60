"""Figure of a discrepancy run: residual over time before/after and where the mismatch was (PNG, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vibro_discrepancy.engine import DiscrepancyRun
from vibro_discrepancy.locate import FLIGHT_FLAG, flight_ratios, impact_ratios


def write_discrepancy_figure(run: DiscrepancyRun, path: str | Path) -> Path | None:
    """Three panels: (1) full-run residual (simulated - measured ball, um) of the baseline and of the
    final model, disagreeing flights shaded; (2) one-step flight shape residual per flight in noise
    units; (3) one-step post-impact velocity error per impact in noise units. None if nothing to plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if run.baseline_run is None or run.baseline_run.simulated_m is None or run.measured is None:
        return None
    path = Path(path)
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax = axes[0]
    b = run.baseline_run
    ax.plot(b.t_s, (b.simulated_m - b.measured_m) * 1e6, lw=0.8, color="tab:red",
            label=f"baseline (D = {b.deviation:.2e})" if b.deviation is not None else "baseline")
    f = run.final_run
    if f is not None and f.simulated_m is not None and run.chain and len(run.chain) > 1:
        ax.plot(f.t_s, (f.simulated_m - f.measured_m) * 1e6, lw=0.8, color="tab:green",
                label=f"with {run.final.label()} (D = {f.deviation:.2e})")
    steps = run.baseline_steps
    if steps is not None:
        r = flight_ratios(steps)
        for k, fl in enumerate(run.measured.flights):
            if np.isfinite(r[k]) and r[k] > FLIGHT_FLAG:
                ax.axvspan(fl.t_s[0], fl.t_s[-1], color="tab:orange", alpha=0.15, lw=0)
    ax.set_ylabel("simulated - measured\nball (um)")
    ax.set_title("Discrepancy: full-run residual (shaded: flights the baseline mispredicts)")
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[1]
    for st, color, label in ((run.baseline_steps, "tab:red", "baseline"), (run.final_steps, "tab:green", "final")):
        if st is None:
            continue
        ax.semilogy(st.flight_t_s, np.maximum(flight_ratios(st), 1e-2), "o", ms=3, color=color, label=label)
    ax.axhline(FLIGHT_FLAG, color="k", lw=0.6, ls="--")
    ax.set_ylabel("flight shape RMS\n(x noise floor)")
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[2]
    cor_noise = float(run.document.get("noise_floor", {}).get("cor") or 0.0)
    for st, color, label in ((run.baseline_steps, "tab:red", "baseline"), (run.final_steps, "tab:green", "final")):
        if st is None:
            continue
        rv, _ = impact_ratios(st, cor_noise)
        for plate, marker in (("top", "^"), ("bottom", "v")):
            sel = (st.impact_plate == plate) & np.isfinite(rv)
            ax.semilogy(st.impact_t_s[sel], np.maximum(rv[sel], 1e-2), marker, ms=4, color=color,
                        label=f"{label}, {plate}")
    ax.axhline(4.0, color="k", lw=0.6, ls="--")
    ax.set_ylabel("post-impact velocity\nerror (x noise)")
    ax.set_xlabel("time (s)")
    ax.legend(loc="upper right", fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
