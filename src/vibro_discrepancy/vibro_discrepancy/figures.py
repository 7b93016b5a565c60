"""Figure of a discrepancy run: residual over time before/after and where the mismatch was (PNG, Agg; optionally
an SVG twin with its text as text).

The top panel shows the deviation the results quote (``baseline_deviation``/``final_deviation``, the report's and
the findings' "D"): D_r, each flight restarted from its measured post-impact state (:func:`.runs.restarted_run`),
labelled with the same value, formatted as the report prints it. The paper's free-running D
(``paper_*_deviation``) is not drawn: with per-impact COR scatter its replay drifts from the record whatever the
model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vibro_discrepancy.engine import DiscrepancyRun
from vibro_discrepancy.locate import FLIGHT_FLAG, flight_ratios, impact_ratios


def percent_text(d: float | None) -> str:
    """A deviation as the report and the findings lines print it (3 significant digits, %)."""
    return "n/a" if d is None else f"{100 * d:.3g} %"


def _plot_windows(ax, t_s: np.ndarray, values: np.ndarray, **kw) -> None:
    """``values`` over ``t_s`` as one line per restarted window (a new window where time does not advance by
    about one frame), so the line does not join one flight's end to the next one's start."""
    t_s = np.asarray(t_s, float)
    if t_s.size < 2:
        return
    dt = np.diff(t_s)
    step = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
    cuts = np.flatnonzero((dt <= 0) | (dt > 1.5 * step)) + 1
    for k, (a, b) in enumerate(zip(np.r_[0, cuts], np.r_[cuts, t_s.size])):
        ax.plot(t_s[a:b], values[a:b], **(kw if k == 0 else {**kw, "label": None}))


def _restarted_panel(ax, run: DiscrepancyRun) -> None:
    """D_r's residual (simulated - measured, um) of the baseline and of the final model, each flight restarted."""
    for r, color, name in ((run.baseline_restarted, "tab:red", "baseline"),
                           (run.final_restarted if run.chain and len(run.chain) > 1 else None, "tab:green",
                            f"with {run.final.label()}" if run.final is not None else "final")):
        if r is None or r.simulated_m is None:
            continue
        _plot_windows(ax, r.t_s, (r.simulated_m - r.measured_m) * 1e6, lw=0.8, color=color,
                      label=f"{name} (D = {percent_text(r.deviation)})")


def write_discrepancy_figure(run: DiscrepancyRun, path: str | Path, svg_path: str | Path | None = None
                             ) -> Path | None:
    """Three panels: (1) the residual of D_r (simulated - measured ball, um; each flight restarted from its
    measured post-impact state) of the baseline and of the final model, labelled with their D_r, disagreeing
    flights shaded; (2) one-step flight shape residual per flight in noise units; (3) one-step post-impact
    velocity error per impact in noise units. Also written as SVG (text kept as text) to ``svg_path`` when
    given. None if nothing to plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if run.baseline_restarted is None or run.baseline_restarted.simulated_m is None or run.measured is None:
        return None
    path = Path(path)
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax = axes[0]
    _restarted_panel(ax, run)
    steps = run.baseline_steps
    if steps is not None:
        r = flight_ratios(steps)
        for k, fl in enumerate(run.measured.flights):
            if np.isfinite(r[k]) and r[k] > FLIGHT_FLAG:
                ax.axvspan(fl.t_s[0], fl.t_s[-1], color="tab:orange", alpha=0.15, lw=0)
    ax.set_ylabel("simulated - measured\nball (um)")
    ax.set_title("Discrepancy: residual of each flight restarted from its measured state (D = D_r)\n"
                 "shaded: flights the baseline mispredicts", fontsize=10)
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
    try:
        fig.savefig(path, dpi=110)
        if svg_path is not None:
            with plt.rc_context({"svg.fonttype": "none", "svg.hashsalt": "vibro"}):
                fig.savefig(svg_path, format="svg", metadata={"Date": None})
    finally:
        plt.close(fig)
    return path
