"""Figures (matplotlib, Agg) and one self-contained HTML report (PNGs inlined as base64, each figure also saved as
SVG beside its PNG and linked).

Figures follow the paper: displacements with fits and impact instants (Fig. 9), COR per impact
(Fig. 10), friction per flight (Fig. 12), accelerometer spectrum (Fig. 7), histogram + normal Q-Q
(Fig. 15-16), simulated vs measured (Fig. 13), and the error-bar summary across recordings (Fig. 14).
"""

from __future__ import annotations

import base64
import html
import time
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Iterator

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from vibro_app.findings_text import effect_label, parameter_text, percent  # noqa: E402
from vibro_app.report_files import FIGURE_FILES, REPORT_HTML, vector_twin  # noqa: E402,F401  (re-exported)
from vibro_app.report_lost import lost_html  # noqa: E402
from vibro_app.report_methods import discrepancy_measures_html, methods_html, uncertainty_html  # noqa: E402
from vibro_app.report_provenance import reproduce_html  # noqa: E402
from vibro_app.report_summary import simulation_rows, structure_rows, summary_html  # noqa: E402
from vibro_app.report_tables import creeping_plates, impacts_table_html, table2_html  # noqa: E402
from vibro_fit.identify import Identification  # noqa: E402
from vibro_fit.statistics import normal_check  # noqa: E402
from vibro_io.dictrack import DicTrack  # noqa: E402
from vibro_io.outputs import atomic_path, atomic_write_text  # noqa: E402
from vibro_model.results import (
    ResultsDocument,  # noqa: E402
    as_document,  # noqa: E402
)
from vibro_model.units import n_to_mn  # noqa: E402

PLATE_COLORS = {"top": "tab:red", "bottom": "tab:blue"}


def _legend(ax, **kw) -> None:
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kw)


def figure_formats() -> set[str]:
    """File name extensions (without the dot) a figure can be saved as."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    return set(FigureCanvasAgg.get_supported_filetypes())


#: inside :func:`vector_twins`: the seconds each SVG twin took (None outside: PNG only)
_TWIN_SECONDS: ContextVar[list[float] | None] = ContextVar("vibro_report_twin_seconds", default=None)


@contextmanager
def vector_twins() -> Iterator[list[float]]:
    """Within the block, every figure :func:`save_figure` writes as PNG is also written as SVG beside it
    (:func:`vibro_app.report_files.vector_twin`); yields the list of the seconds each SVG took."""
    seconds: list[float] = []
    token = _TWIN_SECONDS.set(seconds)
    try:
        yield seconds
    finally:
        _TWIN_SECONDS.reset(token)


def save_svg(fig, path: Path) -> Path:
    """Write ``fig`` as SVG to ``path`` atomically, its text as text (searchable, selectable), no date (the same
    figure gives the same file)."""
    with plt.rc_context({"svg.fonttype": "none", "svg.hashsalt": "vibro"}), atomic_path(path) as tmp:
        fig.savefig(tmp, format="svg", metadata={"Date": None})
    return path


def save_figure(fig, path: Path) -> Path:
    """Lay out ``fig``, write it to ``path`` atomically (110 dpi; format from the suffix) and close it; inside
    :func:`vector_twins` a PNG also gets its SVG twin."""
    fig.tight_layout()
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
        twins = _TWIN_SECONDS.get()
        if twins is not None and path.suffix.lower() == ".png":
            t0 = time.perf_counter()
            save_svg(fig, vector_twin(path))
            twins.append(time.perf_counter() - t0)
    finally:
        plt.close(fig)
    return path


def fig_displacements(track: DicTrack, ident: Identification, path: Path, zoom_cycles: float = 3.0) -> Path:
    fig, axes = plt.subplots(2, 1, figsize=(10, 7))
    t = track.t_s
    s = ident.structure
    f = s.frequency_hz
    for ax, (lo, hi) in zip(axes, ((t[0], t[-1]), (t[0], min(t[-1], t[0] + zoom_cycles / f)))):
        m = (t >= lo) & (t <= hi)
        ax.plot(t[m], track.ball_mm[m], ".", ms=2, color="0.3", label="ball (DIC)")
        ax.plot(t[m], track.structure_mm[m], ".", ms=2, color="tab:green", label="structure (DIC)")
        tt = np.linspace(lo, hi, 2000)
        ax.plot(tt, s.position_mm(tt), "-", lw=0.8, color="tab:green", alpha=0.7, label="sine fit (Eq. 2)")
        first = True
        for fl in ident.flights:
            if fl.t_end_s < lo or fl.t_start_s > hi:
                continue
            t0 = fl.t_start_s
            t1 = fl.t_end_s
            for imp in ident.impacts:
                if imp.flight_after == fl.index:
                    t0 = imp.t_s
                if imp.flight_before == fl.index:
                    t1 = imp.t_s
            tf = np.linspace(t0, t1, 50)
            ax.plot(tf, fl.position_mm(tf), "-", lw=1.0, color="tab:orange" if fl.is_free else "tab:gray",
                    label="parabola fits (Eq. 3)" if first else None)
            first = False
        for imp in ident.impacts:
            if lo <= imp.t_s <= hi:
                ax.axvline(imp.t_s, color=PLATE_COLORS[imp.plate], lw=0.5, alpha=0.5)
        shade_contacts(ax, getattr(ident, "contacts", None) or [], lo, hi)
        ax.set_xlim(lo, hi)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("displacement (mm)")
    axes[0].legend(loc="upper right", fontsize=8)
    title = "Displacements, fits and impact instants (red: top, blue: bottom)"
    if getattr(ident, "contacts", None):
        title += "; shaded: the ball riding a plate"
    axes[0].set_title(title)
    return save_figure(fig, path)


def shade_contacts(ax, contacts, lo: float, hi: float) -> int:
    """Shade each contact phase (the ball riding a plate: ``start_s``..``end_s``, ``plate``; objects or
    results.json mappings) that overlaps [lo, hi] in its plate's colour, one legend entry per plate; returns
    how many were drawn."""
    n, labelled = 0, set()
    for c in contacts:
        get = c.get if isinstance(c, dict) else (lambda k, c=c: getattr(c, k))
        a, b, plate = float(get("start_s")), float(get("end_s")), get("plate")
        if b < lo or a > hi:
            continue
        words = {"top": "upper", "bottom": "lower"}.get(plate, plate)
        ax.axvspan(a, b, color=PLATE_COLORS.get(plate, "0.5"), alpha=0.15, lw=0,
                   label=None if plate in labelled else f"ball riding the {words} plate")
        labelled.add(plate)
        n += 1
    return n


def contacts_html(contacts: list[dict] | None) -> str:
    """The contact phases (results.json ``contacts``) as a table: plate, start, end, duration; empty without."""
    if not contacts:
        return ""
    e = html.escape
    rows = "".join(f"<tr><td>{e({'top': 'upper', 'bottom': 'lower'}.get(c['plate'], c['plate']))}</td>"
                   f"<td>{c['start_s']:.4f}</td><td>{c['end_s']:.4f}</td>"
                   f"<td>{1e3 * (c['end_s'] - c['start_s']):.1f}</td></tr>" for c in contacts)
    return (f"<h2>Contact phases</h2><p>{len(contacts)} phase(s) where the ball rides a plate (moves with it "
            "between the last hop and its release), shaded in the displacement figure.</p>"
            "<table><tr><th>plate</th><th>start (s)</th><th>end (s)</th><th>duration (ms)</th></tr>"
            f"{rows}</table>")


def _reidentified(impacts) -> bool:
    return any(getattr(i, "cor_method", None) not in (None, "paper") for i in impacts)


def fig_cor(impacts, path: Path) -> Path:
    """COR per impact with its propagated 1 sigma; ``impacts``: anything with ``index``, ``plate``, ``cor``,
    ``cor_std`` (and, when re-identified under the discrepancy's final model, ``cor_paper``, shown beside)."""
    fig, ax = plt.subplots(figsize=(9, 4))
    impacts = list(impacts)
    for plate in ("bottom", "top"):
        imps = [i for i in impacts if i.plate == plate]
        if imps:
            ax.errorbar([i.index for i in imps], [i.cor for i in imps], yerr=[i.cor_std for i in imps], fmt="o",
                        ms=4, color=PLATE_COLORS[plate], label=f"{plate} (n={len(imps)})")
            if _reidentified(imps):
                ax.plot([i.index for i in imps], [i.cor_paper for i in imps], "x", ms=4, color=PLATE_COLORS[plate],
                        alpha=0.5, label=f"{plate}, paper's Eq. 16 (before correction)")
    ax.set_xlabel("impact index")
    ax.set_ylabel("COR e" + (" (final model)" if _reidentified(impacts) else " (Eq. 16)"))
    ax.set_title("Coefficient of restitution per impact (error bars: propagated 1 sigma)")
    _legend(ax)
    return save_figure(fig, path)


def fig_friction(ident: Identification, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(9, 4))
    for d, color in (("up", "tab:purple"), ("down", "tab:olive")):
        fls = [f for f in ident.flights if f.is_free and f.direction == d]
        if fls:
            fr = [f.friction_n(ident.mass_kg, ident.g_axis_mps2) for f in fls]
            ax.errorbar([f.index for f in fls], [n_to_mn(v) for v, _ in fr], yerr=[n_to_mn(s) for _, s in fr], fmt="s",
                        ms=4, color=color, label=f"{d} flights")
    ax.axhline(0, color="0.5", lw=0.5)
    ax.set_xlabel("flight index")
    ax.set_ylabel("friction force (mN, positive up)")
    ax.set_title("Friction per free flight, Eq. 17: F = m (2a + g cos(axis tilt))")
    _legend(ax)
    return save_figure(fig, path)


def fig_accel(ident: Identification, path: Path) -> Path | None:
    acc = ident.accel
    if acc is None or not acc.impacts:
        return None
    fig, ax = plt.subplots(figsize=(9, 4))
    ax.semilogy(acc.freqs_hz, acc.mean_spectrum_upper + 1e-12, lw=0.8, label="upper plate")
    ax.semilogy(acc.freqs_hz, acc.mean_spectrum_lower + 1e-12, lw=0.8, label="lower plate")
    for fpk in acc.peaks_hz:
        ax.axvline(fpk, color="0.4", lw=0.5, ls="--")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("|FFT| (averaged over impacts)")
    ax.set_title(f"Accelerometer impact spectrum ({len(acc.impacts)} impacts); peaks: "
                 + ", ".join(f"{p:.0f}" for p in acc.peaks_hz) + " Hz")
    ax.legend()
    return save_figure(fig, path)


def fig_hist_qq(impacts, path: Path) -> Path | None:
    """Histogram and normal Q-Q of the CORs per plate (plates with >= 3 impacts); ``impacts`` as in
    :func:`fig_cor`."""
    impacts = list(impacts)
    plates = [p for p in ("bottom", "top") if sum(i.plate == p for i in impacts) >= 3]
    if not plates:
        return None
    fig, axes = plt.subplots(len(plates), 2, figsize=(10, 3.6 * len(plates)), squeeze=False)
    for row, plate in zip(axes, plates):
        vals = [i.cor for i in impacts if i.plate == plate]
        nc = normal_check(vals)
        ax = row[0]
        ax.hist(vals, bins=nc.edges, density=True, color=PLATE_COLORS[plate], alpha=0.6)
        xs = np.linspace(nc.edges[0], nc.edges[-1], 200)
        if nc.std > 0:
            ax.plot(xs, np.exp(-0.5 * ((xs - nc.mean) / nc.std) ** 2) / (nc.std * np.sqrt(2 * np.pi)), "k-")
        ax.set_title(f"{plate}: mu = {nc.mean:.3f}, sigma = {nc.std:.3f}")
        ax.set_xlabel("COR")
        ax = row[1]
        ax.plot(nc.theoretical_quantiles, nc.ordered_values, "o", ms=4, color=PLATE_COLORS[plate])
        ax.plot(nc.theoretical_quantiles, nc.slope * nc.theoretical_quantiles + nc.intercept, "k-")
        ax.set_title(f"{plate}: normal Q-Q, r = {nc.r:.3f}")
        ax.set_xlabel("theoretical quantiles")
        ax.set_ylabel("ordered COR")
    return save_figure(fig, path)


def fig_simulated(t_s: np.ndarray, measured_mm: np.ndarray, sims: dict[str, np.ndarray], deviations: dict,
                  path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(t_s, measured_mm, ".", ms=2, color="0.3", label="measured ball")
    for name, y in sims.items():
        d = deviations.get(name)
        ax.plot(t_s, y, "-", lw=0.8, label=f"{name} (D = {percent(d)})" if d is not None else name)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("ball displacement (mm)")
    ax.set_title("Simulated vs measured ball displacement (Eq. 18, free-running, each impact's measured COR)")
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def fig_errorbars(rows: list[dict], path: Path) -> Path:
    """Fig. 14 from :func:`vibro_fit.statistics.errorbar_table` rows."""
    fig, ax = plt.subplots(figsize=(8, 4))
    labels = sorted({r["label"] for r in rows})
    for k, plate in enumerate(("bottom", "top")):
        rr = [r for r in rows if r["plate"] == plate]
        x = [labels.index(r["label"]) + (k - 0.5) * 0.15 for r in rr]
        ax.errorbar(x, [r["mean"] for r in rr], yerr=[r["std"] or 0 for r in rr], fmt="o", capsize=4,
                    color=PLATE_COLORS[plate], label=plate)
    ax.set_xticks(range(len(labels)), labels)
    ax.set_ylabel("mean COR +- sigma")
    ax.legend()
    return save_figure(fig, path)


def write_figures(track: DicTrack, ident: Identification, out_dir: str | Path, sim: dict | None = None,
                  impacts=None) -> dict[str, Path]:
    """Write the PNG figures, each with its SVG twin, into ``out_dir``; ``sim`` = {"t_s", "measured_mm",
    "curves": {name: mm}, "deviations": {name: D}} for the simulated-vs-measured figure; ``impacts``: the CORs the
    COR figures show (the results document's, re-identified under the final model; default the identification's).
    Returns {name: PNG path}."""
    with vector_twins():
        return _write_figures(track, ident, Path(out_dir), sim, impacts)


def _write_figures(track: DicTrack, ident: Identification, out: Path, sim: dict | None, impacts) -> dict[str, Path]:
    files = {name: out / file for name, file in FIGURE_FILES.items()}
    impacts = ident.impacts if impacts is None else [i for i in impacts if i.cor is not None]
    figs: dict[str, Path | None] = {
        "displacements": fig_displacements(track, ident, files["displacements"]),
        "cor": fig_cor(impacts, files["cor"]),
        "friction": fig_friction(ident, files["friction"]),
        "accelerometer_spectrum": fig_accel(ident, files["accelerometer_spectrum"]),
        "histogram_qq": fig_hist_qq(impacts, files["histogram_qq"]),
    }
    if sim and sim.get("curves"):
        figs["simulated_vs_measured"] = fig_simulated(sim["t_s"], sim["measured_mm"], sim["curves"],
                                                      sim.get("deviations", {}), files["simulated_vs_measured"])
    return {k: v for k, v in figs.items() if v is not None}


def _img(path: Path) -> str:
    """The PNG inlined, and a link to its SVG twin when there is one beside it."""
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    svg = vector_twin(path)
    link = (f'<p class="vector"><a href="{html.escape(svg.name)}">vector: SVG</a></p>'
            if Path(path).suffix.lower() == ".png" and svg.is_file() else "")
    return f'<img src="data:image/png;base64,{data}" style="max-width:100%">{link}'


def clauses(text: str) -> list[str]:
    """``text`` split at its top-level ';' (not inside parentheses), each clause stripped."""
    out, depth, start = [], 0, 0
    for k, ch in enumerate(text):
        depth += (ch == "(") - (ch == ")")
        if ch == ";" and depth == 0:
            out.append(text[start:k].strip())
            start = k + 1
    out.append(text[start:].strip())
    return [c for c in out if c]


def _where(finding: dict, said: str) -> str:
    """A finding's 'where' without the clauses ``said`` already states (the baseline's location), its effect's
    name in words."""
    effect = str(finding.get("effect", ""))
    parts = [c for c in clauses(str(finding.get("where") or "")) if c not in said]
    return "; ".join(effect_label(effect)[:1].upper() + effect_label(effect)[1:] + c[len(effect):]
                     if effect and c.startswith(effect + " ") else c for c in parts)


def discrepancy_html(disc: dict) -> str:
    """The discrepancy section: D before/after, where the baseline disagrees (once), findings with parameters
    in words and units (results.json's names as tooltips)."""
    e = html.escape
    loc = (disc.get("location") or {}).get("text", "")
    rows = []
    for f in disc.get("findings", []):
        stds = f.get("parameters_std") or {}
        params = "<br>".join(f'<span title="{e(k)}">{e(parameter_text(k, v, stds.get(k)))}</span>'
                             for k, v in f.get("parameters", {}).items()) or "&ndash;"
        sm = f.get("shape_model")
        if sm:   # an unexplained finding's shape, modelled: its parameters, never a catalogue effect's
            sstd = sm.get("parameters_std") or {}
            params = ("<i>shape model" + ("" if sm.get("accepted") else " (not kept)") + ":</i><br>"
                      + "<br>".join(f'<span title="shape_model.parameters.{e(k)}">'
                                    f"{e(parameter_text(k, v, sstd.get(k)))}</span>"
                                    for k, v in (sm.get("parameters") or {}).items() if v is not None))
        alt = (f"<br><i>indistinguishable here from: {e(', '.join(effect_label(a) for a in f['alternatives']))}</i>"
               if f.get("alternatives") else "")
        rows.append(f'<tr><td><b title="{e(str(f.get("effect", "")))}">{e(effect_label(f.get("effect", "")))}</b>'
                    f"{alt}</td><td>{params}</td>"
                    f"<td>{percent(f.get('deviation_before'))} &rarr; {percent(f.get('deviation_after'))}</td>"
                    f"<td>{e(_where(f, loc))}</td></tr>")
    table = ("<table><tr><th>left out</th><th>parameters</th><th>D before &rarr; after</th><th>where else it shows"
             "</th></tr>" + "".join(rows) + "</table>") if rows else "<p>No finding: the baseline model explains the " \
        "recording to within the measurement noise.</p>"
    err = f"<p><b>{e(disc['error'])}</b></p>" if disc.get("error") else ""
    model = disc.get("model")
    return (f'<h2 id="discrepancy">Discrepancy analysis (baseline: constant COR, gravity only, pure sine, vertical)'
            f"</h2>{err}"
            f"<p>D baseline {percent(disc.get('baseline_deviation'))}, final {percent(disc.get('final_deviation'))}"
            f" (final model: {e(effect_label(model)) if model and model != 'baseline' else 'the baseline'}).</p>"
            + (f"<p>Where the baseline disagrees: {e(loc)}</p>" if loc else "") + table)


def dic_quality_html(section: dict | None) -> str:
    """An HTML table of results.json's ``dic_quality`` section (:mod:`vibro_dic.quality`; empty when none)."""
    if not section:
        return ""
    tex = (section.get("texture") or {}).get("bodies", {})
    corr = (section.get("correlation") or {}).get("bodies", {})
    noise = (section.get("texture") or {}).get("noise_gray")

    def f(v, spec=".4g"):
        return "" if v is None else format(v, spec)

    rows = "".join(
        f"<tr><td>{html.escape(name)}</td><td>{t.get('n_usable', '')} of {t.get('n_subsets', '')}</td>"
        f"<td>{f((t.get('mesh_sigma_px') or [None, None])[1])}</td><td>{f(c.get('zncc_median'))}</td>"
        f"<td>{f(c.get('zncc_min'))}</td><td>{c.get('frames_below_zncc_warn', '')}</td>"
        f"<td>{c.get('frames_lost', '')}</td><td>{len(c.get('subsets_lost') or [])}</td>"
        f"<td>{f(c.get('noise_ratio'), '.2f')}</td><td>{f(c.get('sigma_px_from_zncc'))}</td></tr>"
        for name in sorted(set(tex) | set(corr)) for t, c in [(tex.get(name, {}), corr.get(name, {}))])
    return (f"<h2>DIC quality</h2><p>Image noise {f(noise, '.3g')} gray levels; a subset is usable when its "
            "predicted displacement sigma is at most "
            f"{f((section.get('texture') or {}).get('max_subset_sigma_px'), 'g')}"
            " px (docs/real-footage.md).</p><table><tr><th>body</th><th>usable subsets</th>"
            "<th>predicted sigma y (px)</th><th>median ZNCC</th><th>min ZNCC</th><th>frames below warn</th>"
            "<th>frames lost</th><th>subsets lost</th><th>correlation noise / image noise</th>"
            f"<th>sigma y from ZNCC (px)</th></tr>{rows}</table>")



def impacts_model_text(section: dict | None) -> str:
    """Under which model the impacts' CORs were measured (results.json's ``impacts_model``), in words."""
    m = section or {}
    if not m.get("cor_method") or m.get("cor_method") == "paper":
        return "The CORs are the identification's (Eq. 15-16)."
    kept = f"; {m['n_paper']} keep the identification's (Eq. 15-16)" if m.get("n_paper") else ""
    return (f"The CORs of {m.get('n_reidentified', '?')} impacts are measured under the final model "
            f"({effect_label(m['cor_method'])}): impact times where its flights meet, ball velocities from its "
            f"force law{kept}. The COR figures show the identification's (Eq. 16) beside them.")


#: results.json's identification.method (vibro_fit.methods) in words
METHOD_WORDS = {"paper": "Identified as in the paper: each flight's parabola fitted alone, impacts where "
                         "consecutive parabolas meet (Eq. 3, 15).",
                "joint": "Identified jointly: the two flights around each impact refitted together, constrained "
                         "to meet on the plate."}


def _rows(rows: list[tuple[str, str]]) -> str:
    return "".join(f"<tr><th>{html.escape(label)}</th><td>{html.escape(value)}</td></tr>" for label, value in rows)


def write_html(results: ResultsDocument | dict, figures: dict[str, Path], path: str | Path) -> Path:
    """One self-contained HTML page: the summary (:mod:`vibro_app.report_summary`), what was lost
    (:mod:`vibro_app.report_lost`), the methods as run (:mod:`vibro_app.report_methods`), then the details
    (structure, COR and its uncertainty, simulation, discrepancy, DIC quality), the figures (inlined, each linked
    to its SVG twin) and how to reproduce the results (:mod:`vibro_app.report_provenance`). ``results``: the
    document, or a results.json mapping (validated by the codec)."""
    e = html.escape
    results = as_document(results).to_dict()
    titles = {"displacements": "Displacements with fits and impact instants", "cor": "COR per impact",
              "friction": "Friction per flight", "accelerometer_spectrum": "Accelerometer spectrum",
              "histogram_qq": "Histogram and normal Q-Q", "simulated_vs_measured": "Simulated vs measured",
              "discrepancy": "Discrepancy: residual of D (restarted per flight) before/after, and where the "
                             "mismatch was"}
    figs = "".join(f'<h2 id="figure-{e(k)}">{e(titles.get(k, k))}</h2>{_img(p)}' for k, p in figures.items())
    method = (results.get("identification") or {}).get("method")
    page = f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>vibro report</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:2px 8px;text-align:left;vertical-align:top}}
#summary table{{font-size:1.1em}}table.sortable thead th{{position:sticky;top:0;background:#fff}}</style></head><body>
<h1>vibro analysis: {e(str(results.get('recording', '')))}</h1>
{summary_html(results)}
{lost_html(results)}
{methods_html(results)}
<h2>Structure (Eq. 2)</h2><p>{e(METHOD_WORDS.get(method, ""))}</p>
<table>{_rows(structure_rows(results.get("structure")))}</table>
<h2>COR per plate (Table 2)</h2><p>{e(impacts_model_text(results.get("impacts_model")))}</p>
{table2_html(results.get("impacts") or [])}
{uncertainty_html(results)}
{impacts_table_html(results.get("impacts") or [], moving_plates=creeping_plates(results))}
{contacts_html(results.get("contacts"))}
<h2>Simulation deviation D (Eq. 18, free-running with each impact's measured COR)</h2>
<table>{_rows(simulation_rows(results.get("simulation")))}</table>
{discrepancy_html(results.get("discrepancy") or {})}
{discrepancy_measures_html(results)}
{dic_quality_html(results.get("dic_quality"))}
{figs}
{reproduce_html(results.get("provenance"))}
</body></html>"""
    return atomic_write_text(path, page)
