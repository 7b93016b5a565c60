"""The campaign report in OUT/: campaign.json (everything), campaign.csv (one row per run, a table a paper
can use), cor_vs_speed.png and cor_vs_excitation.png (matplotlib), cor_by_orientation.png when the runs hold more
than one rig orientation (rig.yaml ``setup.axis_tilt_deg``: the paper's Fig. 11 study), report.html
(self-contained).

Units: COR dimensionless; impact speed = |v_ball_before - v_structure| (m/s, the relative speed at contact);
excitation frequency Hz, acceleration amplitude m/s^2 (rig.yaml's nominal values); structure amplitude mm.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
from pathlib import Path

from vibro_app.campaign.summary import (
    MIN_GROUP,
    PLATES,
    Z_FLAG,
    excitation_key,
    excitation_label,
    orientation_groups,
    orientation_key,
)
from vibro_io.outputs import atomic_open, atomic_write_text

CAMPAIGN_JSON = "campaign.json"
CAMPAIGN_CSV = "campaign.csv"
REPORT_HTML = "report.html"
FIGURES = {"cor_vs_speed": "cor_vs_speed.png", "cor_vs_excitation": "cor_vs_excitation.png",
           "cor_by_orientation": "cor_by_orientation.png"}
SCHEMA = "vibro.campaign/1"
FLAG_RULE = (f"per plate, among runs of the same nominal excitation and orientation (rig.yaml frequency_hz, "
             f"acceleration_mps2 and setup.axis_tilt_deg; "
             f"groups of at least {MIN_GROUP} runs): z = (run's mean COR - group median) / max(1.4826 x MAD, "
             f"median standard error sigma/sqrt(n) of the group's runs); |z| > {Z_FLAG:g} flags the run")

CSV_COLUMNS = ("run", "status", "reason", "resumed", "excitation_frequency_hz", "excitation_acceleration_mps2",
               "axis_tilt_deg",
               "structure_amplitude_mm", "structure_frequency_hz", "n_impacts",
               "cor_top_mean", "cor_top_std", "cor_top_n", "cor_bottom_mean", "cor_bottom_std", "cor_bottom_n",
               "flagged", "findings", "findings_where", "outputs")


def _fmt(value, spec: str = ".6g") -> str:
    return "" if value is None else format(value, spec)


def findings_text(row: dict) -> str:
    """``effect(param = value ± sigma, ...)`` per finding, '; ' between them."""
    parts = []
    for f in row["findings"]:
        params = ", ".join(f"{k} = {_fmt(p['value'])}" + ("" if p["std"] is None else f" ± {_fmt(p['std'], '.2g')}")
                           for k, p in f["parameters"].items())
        parts.append(f"{f['effect']}({params})")
    return "; ".join(parts)


def flags_text(row: dict) -> str:
    return "; ".join(f"{g['plate']} COR z = {g['z']:+.1f} vs median {g['group_median']:.4f} of {g['group_n']} runs "
                     f"at {g['excitation']}" for g in row["flags"])


def write_campaign_json(out: Path, document: dict) -> Path:
    return atomic_write_text(out / CAMPAIGN_JSON, json.dumps(document, indent=1, allow_nan=False) + "\n")


def write_campaign_csv(out: Path, rows: list[dict]) -> Path:
    with atomic_open(out / CAMPAIGN_CSV, newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(CSV_COLUMNS)
        for r in rows:
            c = r["cor"]
            writer.writerow([
                r["name"], r["status"], r["reason"], int(bool(r.get("resumed"))),
                _fmt(r["excitation"]["frequency_hz"]), _fmt(r["excitation"]["acceleration_mps2"]),
                _fmt(orientation_key(r)),
                _fmt(r["structure"].get("amplitude_mm")), _fmt(r["structure"].get("frequency_hz")),
                "" if r["n_impacts"] is None else r["n_impacts"],
                _fmt(c["top"]["mean"]), _fmt(c["top"]["std"]), c["top"]["n"],
                _fmt(c["bottom"]["mean"]), _fmt(c["bottom"]["std"]), c["bottom"]["n"],
                flags_text(r), findings_text(r), " | ".join(f["where"] for f in r["findings"]), r["outputs"] or "",
            ])
    return out / CAMPAIGN_CSV


def write_figures(out: Path, rows: list[dict]) -> dict[str, Path]:
    """COR per plate against impact speed (every impact, one colour per run) and against the excitation
    group (each run's mean ± sigma); flagged runs ringed in red. Only runs that were analysed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vibro_app.report import save_figure

    ok = [r for r in rows if r["status"] == "ok"]
    n_colours = 10 if len(ok) <= 10 else 20
    paths = {}
    cmap = plt.get_cmap("tab10" if len(ok) <= 10 else "tab20")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, plate in zip(axes, PLATES):
        for i, r in enumerate(ok):
            pts = [(m["speed_mps"], m["cor"]) for m in r["impacts"]
                   if m["plate"] == plate and m["speed_mps"] is not None and m["cor"] is not None]
            if not pts:
                continue
            x, y = zip(*pts)
            flagged = any(g["plate"] == plate for g in r["flags"])
            ax.scatter(x, y, s=18, color=cmap(i % n_colours), label=r["name"] if len(ok) <= 12 else None,
                       edgecolors="red" if flagged else "none", linewidths=1.2)
        ax.set_title(f"{plate} plate")
        ax.set_xlabel("impact speed |v_ball - v_structure| (m/s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("COR")
    if 0 < len(ok) <= 12:
        axes[1].legend(fontsize=7, loc="best")
    fig.suptitle("COR per impact against impact speed, all runs (red ring: run flagged on that plate)")
    paths["cor_vs_speed"] = save_figure(fig, out / FIGURES["cor_vs_speed"])

    keys = sorted({excitation_key(r) for r in ok}, key=lambda k: tuple(-1 if v is None else v for v in k))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, plate in zip(axes, PLATES):
        for gi, key in enumerate(keys):
            members = [r for r in ok if excitation_key(r) == key and r["cor"][plate]["mean"] is not None]
            for j, r in enumerate(members):
                x = gi + (j - (len(members) - 1) / 2) * min(0.6 / max(len(members), 1), 0.12)
                c = r["cor"][plate]
                flagged = any(g["plate"] == plate for g in r["flags"])
                ax.errorbar(x, c["mean"], yerr=c["std"] or 0.0, fmt="o", ms=5, capsize=3,
                            color="red" if flagged else "C0")
        ax.set_xticks(range(len(keys)), [excitation_label(k) for k in keys], rotation=20, fontsize=8)
        ax.set_xlim(-0.5, len(keys) - 0.5)
        ax.set_title(f"{plate} plate")
        ax.set_xlabel("nominal excitation (rig.yaml)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("COR (run mean ± σ)")
    fig.suptitle("COR per run against the excitation (red: flagged)")
    paths["cor_vs_excitation"] = save_figure(fig, out / FIGURES["cor_vs_excitation"])
    groups = orientation_groups(rows)
    if len(groups) >= 2:
        paths["cor_by_orientation"] = orientation_figure(groups, out / FIGURES["cor_by_orientation"])
    return paths


def orientation_figure(groups: list[dict], path: Path) -> Path:
    """COR top and bottom per rig orientation (:func:`.summary.orientation_groups`): the pooled impacts' mean
    with its 95 % confidence interval, one x position per ``setup.axis_tilt_deg`` (the paper's Fig. 11)."""
    import matplotlib.pyplot as plt

    from vibro_app.report import save_figure

    fig, ax = plt.subplots(figsize=(7, 4.2))
    x = list(range(len(groups)))
    for plate, dx, colour in (("top", -0.08, "C3"), ("bottom", 0.08, "C0")):
        pts = [(xi + dx, g["cor"][plate]) for xi, g in zip(x, groups) if g["cor"][plate]["mean"] is not None]
        if not pts:
            continue
        ax.errorbar([p[0] for p in pts], [c["mean"] for _, c in pts],
                    yerr=[c["ci95_half_width"] or 0.0 for _, c in pts], fmt="o", ms=6, capsize=4, color=colour,
                    label=f"{plate} plate")
    ax.set_xticks(x, [f"{g['axis_tilt_deg']:g}°\n({sum(g['cor'][p]['n'] for p in PLATES)} impacts, "
                      f"{len(g['runs'])} run{'s' if len(g['runs']) != 1 else ''})" for g in groups], fontsize=8)
    ax.set_xlim(-0.5, len(groups) - 0.5)
    ax.set_xlabel("rig orientation: motion axis from vertical (rig.yaml setup.axis_tilt_deg)")
    ax.set_ylabel("COR (mean ± 95 % CI of the mean)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.suptitle("COR per plate and orientation (impacts pooled over the runs at each orientation)")
    return save_figure(fig, path)


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img alt="{html.escape(path.name)}" src="data:image/png;base64,{data}" style="max-width:100%">'


def write_report_html(out: Path, document: dict, figures: dict[str, Path]) -> Path:
    """A self-contained page: summary, the runs' table, failed runs with their reason, the flag rule, figures."""
    e = html.escape
    rows = document["runs"]
    buf = io.StringIO()
    buf.write("<!doctype html><html><head><meta charset='utf-8'><title>vibro campaign</title><style>"
              "body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse;font-size:13px}"
              "td,th{border:1px solid #ccc;padding:3px 6px;vertical-align:top}tr.failed{background:#fde}"
              "tr.flagged{background:#ffe9c7}</style></head><body>")
    s = document["summary"]
    buf.write(f"<h1>vibro campaign</h1><p>{s['n_runs']} runs: {s['n_ok']} analysed ({s['n_resumed']} resumed from "
              f"earlier outputs), {s['n_failed']} failed, {s['n_flagged']} flagged. "
              f"vibro {e(document['vibro_version'])}.</p><p>Flag rule: {e(FLAG_RULE)}.</p>")
    buf.write("<table><tr><th>run</th><th>excitation</th><th>structure</th><th>impacts</th><th>COR top</th>"
              "<th>COR bottom</th><th>findings (parameter ± σ; where)</th><th>flags / reason</th></tr>")
    for r in rows:
        cls = "failed" if r["status"] != "ok" else ("flagged" if r["flags"] else "")
        c = r["cor"]
        cor = {p: "" if c[p]["mean"] is None else f"{c[p]['mean']:.4f} ± {_fmt(c[p]['std'], '.4f')} (n {c[p]['n']})"
               for p in PLATES}
        link = (f"<a href='{e(Path(r['name']).as_posix())}/report.html'>{e(r['name'])}</a>"
                if r["status"] == "ok" else e(r["name"]))
        st = r["structure"]
        struct = "" if st.get("amplitude_mm") is None else f"{st['amplitude_mm']:.4f} mm, {st['frequency_hz']:.4f} Hz"
        finds = "<br>".join(f"<b>{e(f['effect'])}</b> " + e(", ".join(
            f"{k} = {_fmt(p['value'], '.4g')}" + ("" if p["std"] is None else f" ± {_fmt(p['std'], '.2g')}")
            for k, p in f["parameters"].items())) + f"<br><small>{e(f['where'])}</small>" for f in r["findings"])
        note = e(r["reason"]) if r["status"] != "ok" else e(flags_text(r))
        setting = excitation_label(excitation_key(r) + (orientation_key(r),))
        buf.write(f"<tr class='{cls}'><td>{link}</td><td>{e(setting)}</td>"
                  f"<td>{e(struct)}</td><td>{'' if r['n_impacts'] is None else r['n_impacts']}</td>"
                  f"<td>{e(cor['top'])}</td><td>{e(cor['bottom'])}</td><td>{finds}</td><td>{note}</td></tr>")
    buf.write("</table>")
    for path in figures.values():
        buf.write(f"<p>{_img(path)}</p>")
    buf.write(f"<p>Tables: <a href='{CAMPAIGN_CSV}'>{CAMPAIGN_CSV}</a>, <a href='{CAMPAIGN_JSON}'>{CAMPAIGN_JSON}</a>"
              "</p></body></html>\n")
    return atomic_write_text(out / REPORT_HTML, buf.getvalue())
