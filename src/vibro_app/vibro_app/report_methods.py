"""The report's *Methods (as run)* and *Uncertainty* sections, and the sentence saying which deviation D is which.

Generated from what was run: every number is read from results.json (its sections and ``provenance``: the
settings the analysis ran with and rig.yaml's text as read), none is typed here. The equations carry the paper's
numbers (Eq. 1 ZNCC, Eq. 2/13 structure sine, Eq. 3/14 flight parabolas, Eq. 15 impact times, Eq. 16 COR,
Eq. 17 friction, Eq. 18 deviation D); an equation the run did not use says so. Rows that a test reads back carry
a ``data-key``.
"""

from __future__ import annotations

import html
import math
import re
import statistics
from typing import Any, Mapping, Sequence

from vibro_app.findings_text import EFFECT_LABELS, effect_label, percent, value_pm

Row = tuple[str, str, str]   # (data-key, label, value): plain text, escaped when printed

#: the paper's equations as the code uses them (HTML; the symbols of the paper)
EQUATIONS = {
    "1": "γ = Σ<sub>i,j</sub> [I<sub>1</sub> − Ī<sub>1</sub>][I<sub>2</sub>(x+d) − Ī<sub>2</sub>] / "
         "√(Σ<sub>i,j</sub> [I<sub>1</sub> − Ī<sub>1</sub>]<sup>2</sup> · Σ<sub>i,j</sub> [I<sub>2</sub>(x+d) − "
         "Ī<sub>2</sub>]<sup>2</sup>)",
    "2, 13": "Y<sub>s</sub>(t) = A sin(ωt + φ) + B, least squares over the structure's frames",
    "3, 14": "Y<sub>b</sub><sup>i</sup>(t) = a<sub>i</sub> t<sup>2</sup> + b<sub>i</sub> t + c<sub>i</sub>, "
             "least squares over the frames of flight i",
    "15": "(a<sub>i</sub> − a<sub>i−1</sub>) t<sub>i</sub><sup>2</sup> + (b<sub>i</sub> − b<sub>i−1</sub>) "
          "t<sub>i</sub> + c<sub>i</sub> − c<sub>i−1</sub> = 0",
    "16": "e<sub>i</sub> = −(Ẏ<sub>b</sub><sup>i</sup>(t<sub>i</sub>) − Ẏ<sub>s</sub>(t<sub>i</sub>)) / "
          "(Ẏ<sub>b</sub><sup>i−1</sup>(t<sub>i</sub>) − Ẏ<sub>s</sub>(t<sub>i</sub>))",
    "17": "F<sub>friction</sub><sup>i</sup> = m<sub>b</sub> (2 a<sub>i</sub> + g)",
    "18": "D = √(∫ (Y<sub>b</sub><sup>sim</sup> − Y<sub>b</sub><sup>exp</sup>)<sup>2</sup> dt / "
          "∫ (Y<sub>b</sub><sup>exp</sup>)<sup>2</sup> dt)",
}


def rig_of(results: Mapping[str, Any]) -> dict[str, Any]:
    """rig.yaml as the analysis read it (results.json ``provenance.rig_yaml``, parsed), {} when not recorded."""
    import yaml

    text = (results.get("provenance") or {}).get("rig_yaml")
    if not text:
        return {}
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        return {}
    return data if isinstance(data, dict) else {}


def _get(d: Any, *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, Mapping):
            return None
        d = d.get(k)
    return d


def _num(v: Any, spec: str = "g", unit: str = "") -> str:
    if v is None or isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return "n/a"
    return format(v, spec) + (f" {unit}" if unit else "")


def _times(k: float, v: Any) -> float | None:
    """``k * v``, None for an unknown ``v``."""
    return None if v is None else k * float(v)


def _roi(roi: Any) -> str:
    return f"x {roi[0]}, y {roi[1]}, {roi[2]} × {roi[3]} px" if isinstance(roi, Sequence) and len(roi) == 4 else "n/a"


def _table(rows: Sequence[Row], table_id: str) -> str:
    e = html.escape
    return (f'<table id="{e(table_id)}">' + "".join(f'<tr data-key="{e(k)}"><th>{e(label)}</th><td>{e(value)}</td></tr>'
                                                    for k, label, value in rows) + "</table>")


# ---------------------------------------------------------------- DIC
def dic_rows(results: Mapping[str, Any]) -> list[Row]:
    """The DIC as run: camera, subset size, mesh step and count, ROIs, ball method, search and sub-pixel options."""
    rig, dq = rig_of(results), results.get("dic_quality") or {}
    settings = _get(results, "provenance", "settings", "dic")
    tex = _get(dq, "texture", "bodies") or {}
    rows: list[Row] = [("camera", "camera", f"{_num(_get(rig, 'camera', 'fps'), 'g', 'frames/s')}, image scale "
                                            f"{_num(_get(rig, 'camera', 'mm_per_px'), 'g', 'mm/px')}")]
    if not dq and settings is None:
        return rows + [("dic", "DIC", "not run in this analysis: the track was read from a file (see Reproduce)")]
    rows += [("dic.subset", "subset size", _num(_get(rig, "dic", "subset_px"), "d", "px")),
             ("dic.mesh_step", "mesh spacing", _num(_get(rig, "dic", "mesh_step_px"), "d", "px"))]
    for body in sorted(tex):
        t = tex[body]
        rows.append((f"dic.mesh.{body}", f"{body} mesh", f"{t.get('n_subsets')} subsets of {t.get('subset_px')} px "
                                                          f"({t.get('n_usable')} usable), ROI {_roi(t.get('roi'))}"))
    if dq.get("ball_method"):
        how = {"mesh": "a mesh of subsets (Eq. 1 and IC-GN)", "outline": "its outline (sub-pixel edges and a circle "
                                                                            "fit; Eq. 1 not used for the ball)"}
        rows.append(("dic.ball_method", "ball tracked by", f"{how.get(dq['ball_method'], dq['ball_method'])}; chosen "
                                                           f"by {dq.get('ball_method_source', '?')}: "
                                                           f"{dq.get('ball_method_reason', '')}"))
    tr = (settings or {}).get("tracking") or {}
    if tr:
        sub = ("inverse-compositional Gauss-Newton (IC-GN), converged at a step of "
               f"{_num(tr.get('tol_px'))} px, {tr.get('taps')}-tap interpolation" if tr.get("method") == "icgn"
               else f"{tr.get('method')} (parabola through the ZNCC peak)")
        rows += [("dic.search", "integer search (Eq. 1)", f"± {tr.get('search_px')} px around the prediction; a "
                                                          f"point kept at ZNCC ≥ {_num(tr.get('zncc_min'))}"),
                 ("dic.subpixel", "sub-pixel refinement", sub),
                 ("dic.mesh_rule", "a body's displacement", "robust mean of its mesh: points beyond "
                                                             f"{_num(tr.get('outlier_k'))} robust sigmas (at least "
                                                             f"{_num(tr.get('outlier_floor_px'))} px) left out; the "
                                                             f"body lost when fewer than "
                                                             f"{_num(100 * tr['min_valid_fraction'])} % of its points "
                                                             "are kept" if tr.get("min_valid_fraction") else ""),
                 ("dic.reseed", "reference", f"frame 0; the search re-seeded every "
                                             f"{settings.get('reseed_every_frames')} frames")]
    bias_row = subpixel_bias_row(results)
    if bias_row is not None:
        rows.append(bias_row)
    if _get(dq, "texture", "max_subset_sigma_px") is not None:
        rows.append(("dic.texture", "texture check", f"image noise {_num(_get(dq, 'texture', 'noise_gray'), '.3g')} "
                                                     "gray levels; a subset is used when its predicted sigma is at "
                                                     f"most {_num(_get(dq, 'texture', 'max_subset_sigma_px'))} px"))
    return rows


def subpixel_bias_row(results: Mapping[str, Any]) -> Row | None:
    """DIC's sub-pixel bias (results.json ``dic_bias``): per body, its amplitude and whether it was taken out, and
    why not; None without the section."""
    section = results.get("dic_bias")
    if not isinstance(section, Mapping):
        return None
    parts = []
    for body in ("structure", "ball"):
        b = section.get(body) or {}
        if b.get("applied"):
            amp, amp_std = _num(b.get("amplitude_px"), ".2g", "px"), _num(b.get("amplitude_std_px"), ".1g")
            before = _num(_times(1e3, b.get("rms_residual_before_mm")), ".3g")
            after = _num(_times(1e3, b.get("rms_residual_after_mm")), ".3g", "µm")
            parts.append(f"{body}: {amp} (± {amp_std}), taken out; residual {before} → {after}")
        else:
            parts.append(f"{body}: not taken out ({b.get('reason') or 'not measured'})")
    return ("dic.subpixel_bias", "sub-pixel bias (S-curve)",
            "b(d) = Σ a_m sin 2πmd + b_m cos 2πmd of the displacement d in pixels, fitted with each body's motion "
            "model and taken out where told from noise; the identification ran on the corrected track. "
            + "; ".join(parts))


# ---------------------------------------------------------------- identification
def _flight_points(results: Mapping[str, Any]) -> str:
    n = [f["n_points"] for f in results.get("flights") or [] if f.get("n_points")]
    if not n:
        return "no flight fitted"
    return f"{min(n)} to {max(n)} frames per flight (median {statistics.median(n):g})"


def fit_rows(results: Mapping[str, Any]) -> list[Row]:
    """Fit windows and thresholds: the flight segmentation, the structure fits, the noise they are judged by."""
    ident = results.get("identification") or {}
    seg = _get(results, "provenance", "settings", "identification", "segmentation") or {}
    id_settings = _get(results, "provenance", "settings", "identification") or {}
    rig = rig_of(results)
    noise = ident.get("noise_mm")
    rows: list[Row] = [("fit.noise", "ball position noise σ (from the track's second differences)",
                        _num(None if noise is None else 1e3 * noise, ".3g", "µm"))]
    if seg:
        rows += [("fit.contact", "a contact frame", f"|acceleration + g| > max({_num(seg.get('k_sigma'))} σ of the "
                                                    f"estimate, {_num(seg.get('min_threshold_mps2'))} m/s²), "
                                                    f"g = {_num(seg.get('g_mps2'))} m/s²"),
                 ("fit.impact_frames", "an impact", f"a cluster of at most {seg.get('max_impact_frames')} contact "
                                                    "frames, left out of both flights' fits; longer: a contact phase"),
                 ("fit.min_points", "a flight fitted (Eq. 3, 14)", f"from {seg.get('min_points')} frames"),
                 ("fit.free", "a free flight", f"parabola residual rms ≤ {_num(seg.get('rms_factor'))} σ + "
                                               f"{_num(_times(1e3, seg.get('rms_floor_mm')))}"
                                               f" µm and |2a + g| ≤ {_num(seg.get('max_friction_g'))} g")]
    flights = results.get("flights") or []
    rows.append(("fit.flights", "flights", f"{len(flights)} fitted, {sum(bool(f.get('free')) for f in flights)} "
                                           f"free; {_flight_points(results)}; weights: "
                                           f"{ident.get('weights') or id_settings.get('weights') or 'none'}"))
    st = results.get("structure") or {}
    residual = _num(_times(1e3, st.get("rms_residual_mm")), ".3g", "µm")
    rows.append(("fit.structure", "structure sine (Eq. 2, 13)",
                 f"one fit over {st.get('n_points')} frames, residual rms {residual}"))
    f_nom = _get(rig, "excitation", "frequency_hz")
    hist = id_settings.get("local_structure_history_s", "absent")
    if hist is None and f_nom:
        hist_text = f"one nominal drive period (1/{_num(f_nom)} Hz = {_num(1e3 / f_nom, '.4g', 'ms')})"
    else:
        hist_text = "n/a" if hist in (None, "absent") else _num(1e3 * hist, ".4g", "ms")
    rows.append(("fit.local_structure", "structure velocity at an impact", "a local sine fit from "
                                                                           f"{hist_text} before the flight before the "
                                                                           "impact to the end of the flight after it"))
    plates = plate_motion_row(results)
    if plates is not None:
        rows.append(plates)
    return rows


def plate_motion_row(results: Mapping[str, Any]) -> Row | None:
    """Each plate's height against the tracked structure (results.json ``plate_motion``): still, a creep taken
    into its CORs, or a step; None without the section."""
    section = results.get("plate_motion")
    if not isinstance(section, Mapping):
        return None
    parts = []
    for plate in ("top", "bottom"):
        m = section.get(plate)
        if not isinstance(m, Mapping):
            continue
        shape = m.get("shape")
        if shape == "creep" and m.get("applied"):
            parts.append(f"{plate}: creeps {_num(m.get('rate_um_per_s'), '+.3g', 'µm/s')} (± "
                         f"{_num(m.get('rate_std_um_per_s'), '.2g')}); its velocity taken into its CORs (up to "
                         f"{_num(m.get('cor_shift_max'), '.2g')})")
        elif shape == "step":
            parts.append(f"{plate}: contact level steps once, {_num(m.get('step_um'), '+.3g', 'µm')} at "
                         f"{_num(m.get('step_time_s'), '.3f', 's')}; CORs unchanged")
        else:
            parts.append(f"{plate}: {m.get('reason') or shape}")
    return ("fit.plate_motion", "plate height against the structure",
            "the contact levels (ball − structure at each impact) fitted against time (polynomial of degree 0-3 "
            "or one step, by BIC); a creep beyond 5 σ that moves a COR by ≥ 0.2 of its noise is the plate's "
            "velocity in Eq. 16. " + "; ".join(parts))



def threshold_rows(results: Mapping[str, Any]) -> list[Row]:
    """The thresholds the checks ran with: DIC quality, physical floors, accelerometer impacts."""
    rows: list[Row] = []
    corr = _get(results, "dic_quality", "correlation") or {}
    if corr:
        rows.append(("thr.dic", "DIC quality", f"a frame flagged below ZNCC {_num(corr.get('zncc_warn'))}; the run "
                                               f"refused when a body is lost in more than "
                                               f"{_num(_times(100, corr.get('max_lost_fraction')))} % "
                                               f"of the frames; correlation noise flagged above "
                                               f"{_num(corr.get('max_noise_ratio'))} × the image noise"))
    fr = _get(results, "consistency", "checks", "friction") or {}
    if fr:
        rows.append(("thr.friction", "friction floor", f"{_num(fr.get('floor_of_weight'))} of the ball's weight "
                                                       f"({_num(_times(1e6, fr.get('floor_n')), '.3g', 'µN')}); "
                                                       f"significance at z > {_num(fr.get('z_limit'), '.3g')}"))
    acc = results.get("accelerometers") or {}
    if acc:
        hp = _get(results, "provenance", "settings", "identification", "accel_highpass_hz")
        rows.append(("thr.accel", "accelerometer impacts", f"threshold {_num(acc.get('threshold_mps2'), '.4g')} m/s² "
                                                           f"after a {_num(hp)} Hz high-pass"))
    return rows



def drive_rows(results: Mapping[str, Any]) -> list[Row]:
    """The drive model (results.json ``drive``): stationary or what moved, the windows and floors it was tested in."""
    d = results.get("drive") or {}
    if not d:
        return [("drive", "drive", "not identified (the structure does not move)")]
    fl = d.get("floors") or {}
    window = (f"windows of {d.get('window_cycles')} drive cycles "
              f"({_num(_times(1e3, d.get('window_s')), '.4g', 'ms')}); "
              f"family-wise false-alarm probability {_num(fl.get('alpha'))}, floors "
              f"{_num(_times(100, fl.get('amplitude_ratio')))} % of the "
              f"amplitude and {_num(_times(1e3, fl.get('phase_rad')))} mrad of phase")
    if not d.get("tested"):
        verdict = f"not tested: {d.get('reason') or 'too short'}"
    elif d.get("stationary"):
        a, p = d.get("amplitude") or {}, d.get("phase") or {}
        verdict = ("stationary: the paper's one sine (Eq. 2) over the whole take; amplitude change "
                   f"{value_pm(_times(100, a.get('change_ratio')), _times(100, a.get('change_ratio_std')), '%')}, "
                   "phase excursion "
                   f"{value_pm(_times(1e3, p.get('span_rad')), _times(1e3, p.get('span_std_rad')), 'mrad')}")
    else:
        verdict = f"not stationary: {d.get('words') or d.get('reason') or 'see the drive section'}"
    return [("drive", "drive", verdict), ("drive.windows", "tested in", window)]




def clock_rows(results: Mapping[str, Any]) -> list[Row]:
    """The camera-to-DAQ clock (results.json ``accelerometers.clock_offset``)."""
    acc = results.get("accelerometers") or {}
    c = acc.get("clock_offset") or {}
    if not acc:
        return [("clock", "camera-DAQ clock", "no accelerometers in this recording")]
    if not c.get("determined"):
        return [("clock", "camera-DAQ clock", f"offset not determined: {c.get('reason') or 'too few impacts matched'}")]
    offset = value_pm(_times(1e3, c.get("offset_s")), _times(1e3, c.get("offset_std_s")), "ms")
    rate = (f"rate {value_pm(c.get('rate_ppm'), c.get('rate_std_ppm'), 'ppm')} applied" if c.get("rate_significant")
            else f"rate taken as {_num(c.get('rate_ppm'))} ppm (fitted "
                 f"{value_pm(c.get('fitted_rate_ppm'), c.get('rate_std_ppm'), 'ppm')}, not significant)")
    return [("clock", "camera-DAQ clock", f"DAQ time − camera time = {offset}; {rate}; from {c.get('n_matched')} "
                                          f"impacts matched of {c.get('n_accel_impacts')} (accelerometers) and "
                                          f"{c.get('n_dic_impacts')} (camera)")]



# ---------------------------------------------------------------- equations
def _impact_words(results: Mapping[str, Any]) -> str:
    impacts = results.get("impacts") or []
    method = _get(results, "identification", "method") or "paper"
    words = (f"{len(impacts)} impacts, each the root of Eq. 15 between the last frame of the flight before and "
             "the first of the flight after" if method == "paper" else
             f"{len(impacts)} impacts from the two flights around each fitted together, constrained to meet on the "
             "plate (replaces Eq. 15)")
    im = results.get("impacts_model") or {}
    if im.get("cor_method") and im.get("cor_method") != "paper":
        words += (f"; {im.get('n_reidentified')} then measured again under the final model "
                  f"({effect_label(im['cor_method'])}): where its flights meet")
    return words


def equation_rows(results: Mapping[str, Any]) -> list[tuple[str, str, str]]:
    """(equation number, formula HTML, as run: escaped text) of each equation, 'not used' where the run did not."""
    e = html.escape
    rig, dq = rig_of(results), results.get("dic_quality") or {}
    impacts = results.get("impacts") or []
    n_cor = sum(i.get("cor") is not None for i in impacts)
    flights = results.get("flights") or []
    free = sum(bool(f.get("free")) for f in flights)
    body_zncc = ", ".join(f"{b} median ZNCC {_num(c.get('zncc_median'), '.4f')}"
                          for b, c in sorted((_get(dq, "correlation", "bodies") or {}).items()))
    sim, disc = results.get("simulation") or {}, results.get("discrepancy") or {}
    seg = _get(results, "provenance", "settings", "identification", "segmentation") or {}
    rows = [
        ("1", ("every frame's integer search of each subset against frame 0; " + body_zncc) if dq else
         "not used here: the DIC track was read from a file"),
        ("2, 13", f"one sine over {_get(results, 'structure', 'n_points')} frames, and a local one at each impact"),
        ("3, 14", f"{len(flights)} flights fitted, {free} free"),
        ("15", _impact_words(results) if impacts else "not used: no impact"),
        ("16", f"{n_cor} CORs (per plate in Table 2)" if impacts else "not used: no impact"),
        ("17", f"{free} free flights, ball mass {_num(_get(rig, 'ball', 'mass_kg'))} kg (rig.yaml), g = "
               f"{_num(seg.get('g_mps2'))} m/s²" if free else "not used: no free flight"),
        ("18", f"the simulation (COR model {percent(_get(sim, 'cor_model', 'deviation'))}, Hertz model "
               f"{percent(_get(sim, 'hertz_model', 'deviation'))}) and the discrepancy analysis (D "
               f"{percent(disc.get('baseline_deviation'))} → {percent(disc.get('final_deviation'))})"),
    ]
    return [(n, EQUATIONS[n], e(text)) for n, text in rows]


# ---------------------------------------------------------------- the final model and why
def words_of(text: str) -> str:
    """``text`` with every effect name (``coulomb_friction``) in words (Coulomb friction)."""
    return re.sub(r"\b(" + "|".join(map(re.escape, sorted(EFFECT_LABELS, key=len, reverse=True))) + r")\b",
                  lambda m: effect_label(m.group(1)), str(text))


def model_html(results: Mapping[str, Any]) -> str:
    """The final discrepancy model and why: per stage of the selection, what was chosen (among the candidates
    that pass their test, the one that fits best), the residual left in noise floors, and every candidate tested
    with its p-value and the engine's words."""
    e = html.escape
    disc = results.get("discrepancy") or {}
    stages = disc.get("stages") or {}
    if not stages:
        why = disc.get("error") or disc.get("skipped")
        return f"<p>No discrepancy model: {e(str(why))}.</p>" if why else ""
    model = disc.get("model")
    head = ("<p>Final model: the baseline (constant COR, gravity only, pure sine, vertical)"
            + (f" with {e(effect_label(model))}" if model and model != "baseline" else "")
            + f"; D {percent(disc.get('baseline_deviation'))} → {percent(disc.get('final_deviation'))} "
              '(findings: <a href="#discrepancy">Discrepancy analysis</a>). Chosen stage by stage:</p>')
    rows = []
    for name, st in stages.items():
        chosen = ", ".join(effect_label(c) for c in st.get("chosen") or []) or "nothing"
        notes = "; ".join(words_of(n) for n in st.get("notes") or [])
        left = st.get("residual_x_noise")
        cands = "<br>".join(
            f"{e(effect_label(c.get('candidate', '?')))}: {'passes' if c.get('accepted') else 'fails'} its test, "
            f"p = {_num(c.get('p_value'), '.2g')}" + (f", {e(words_of(c['note']))}" if c.get("note") else "")
            for c in st.get("candidates") or [])
        notes_html = f"<br><i>{e(notes)}</i>" if notes else ""
        rows.append(f'<tr data-key="stage.{e(name)}"><th>{e(name)}</th><td>{e(chosen)}</td>'
                    f"<td>{_num(left, '.3g')}</td><td>{cands}{notes_html}</td></tr>")
    return (head + '<table id="model-stages"><tr><th>stage</th><th>chosen</th><th>residual left (× noise floor)</th>'
            "<th>candidates tested</th></tr>" + "".join(rows) + "</table>")


def methods_html(results: Mapping[str, Any]) -> str:
    """The *Methods (as run)* section."""
    eqs = "".join(f'<tr data-key="eq.{n}"><th>Eq. {n}</th><td>{formula}</td><td>{text}</td></tr>'
                  for n, formula, text in equation_rows(results))
    return ('<section id="methods"><h2>Methods (as run)</h2><p>The equations of the paper (its numbering) as this '
            "run used them, and the parameters it ran with, read from these results and rig.yaml as used.</p>"
            '<table id="equations"><tr><th>equation</th><th>form</th><th>in this run</th></tr>' + eqs + "</table>"
            "<h3>DIC</h3>" + _table(dic_rows(results), "methods-dic")
            + "<h3>Fit windows and thresholds</h3>" + _table(fit_rows(results) + threshold_rows(results),
                                                             "methods-fit")
            + "<h3>Drive and clocks</h3>" + _table(drive_rows(results) + clock_rows(results), "methods-drive")
            + "<h3>Discrepancy model</h3>" + model_html(results) + "</section>")


# ---------------------------------------------------------------- uncertainty
def uncertainty_html(results: Mapping[str, Any]) -> str:
    """What an impact's COR sigma contains and what it does not; where the per-plate inference is."""
    e = html.escape
    impacts = [i for i in results.get("impacts") or [] if i.get("cor_std") is not None]
    if not impacts:
        return ('<section id="uncertainty"><h3>Uncertainty of the COR</h3><p>No impact carries a COR sigma.</p>'
                "</section>" if results.get("impacts") else "")
    rig = rig_of(results)
    stds = sorted(float(i["cor_std"]) for i in impacts)
    noise = _get(results, "identification", "noise_mm")
    im = results.get("impacts_model") or {}
    local = sum(str(i.get("cor_method") or "").endswith("local_structure") for i in impacts)
    scale = _get(rig, "camera", "mm_per_px")
    rel = _get(rig, "camera", "mm_per_px_rel_std")
    contains = [f"The DIC noise of the ball track (σ = {_num(_times(1e3, noise), '.3g', 'µm')} per frame) and of the "
                "structure track, propagated to first order through the two flight fits around the impact (Eq. 3, "
                "14) and the local structure fit (Eq. 2, 13) to the impact time (Eq. 15) and the COR (Eq. 16); each "
                "flight's noise at least the noise pooled over every flight (one flight's own rests on a few tens "
                "of frames)."]
    if im.get("cor_method") and im.get("cor_method") != "paper":
        contains.append(f"For the {im.get('n_reidentified')} impacts measured again under the final model, the same "
                        "propagation through that model's flight fits, with the uncertainty of the force "
                        "coefficients every flight shares (it moves every impact's COR the same way).")
    if local:
        contains.append(f"For the {local} impacts measured with the local structure velocity, also how much the value "
                        "rests on that local model.")
    model = sorted(float(i["cor_std_model"]) for i in impacts if i.get("cor_std_model") is not None)
    if model:
        contains.append(f"For the {len(model)} impacts near which the model leaves a significant smooth residual (the "
                        "flights' or the structure's, pooled per plate and side), what that residual's slope does to "
                        f"the velocities: model error, median {_num(statistics.median(model), '.2g')} "
                        "(cor_std_model in impacts.csv and results.json).")
    scale_text = (f"The image scale ({_num(scale)} mm/px"
                  + (f", ± {_num(100 * rel, '.2g')} %" if rel is not None else "")
                  + ") multiplies the relative velocities before and after the impact alike and cancels in their "
                    "ratio (Eq. 16): its uncertainty is not in the COR sigma (it is in the velocities, the "
                    "friction and the amplitude).")
    if im.get("cor_method") and im.get("cor_method") != "paper":
        scale_text += (" Under the final model, whose flights share a fixed g, a scale error would show as a constant "
                       "flight force instead (the discrepancy analysis says where a scale error could explain a "
                       "finding).")
    not_in = ("Not in the sigma: model error the residuals do not show (the flight law between frames and the "
              "structure's motion as the model has them; the discrepancy analysis judges that model: D "
              f"{percent(_get(results, 'discrepancy', 'final_deviation'))} for the final one), systematic DIC errors "
              "other than the sub-pixel bias measured and taken out (see Methods, DIC; motion out of the image "
              "plane) and the impact's own duration (the frames next to it are left out; the contact is taken as "
              "instantaneous).")
    scatter = _get(results, "discrepancy", "contact_scatter", "all") or {}
    plate = ("The per-plate standard error and 95 % interval of the mean (<a href=\"#table2\">Table 2</a>) come from "
             "the scatter of the impacts' CORs (std / √n), not from the sigmas above")
    if scatter.get("sigma") is not None and scatter.get("noise_sigma"):
        plate += (f"; that scatter ({_num(scatter['sigma'], '.3g')} per impact) is "
                  f"{_num(scatter['sigma'] / scatter['noise_sigma'], '.3g')} × the measurement noise "
                  f"({_num(scatter['noise_sigma'], '.2g')}), a property of the contact")
    return ('<section id="uncertainty"><h3>Uncertainty of the COR</h3><p>Each impact\'s sigma (median '
            f"{_num(statistics.median(stds), '.2g')}, {_num(stds[0], '.2g')} to {_num(stds[-1], '.2g')} over "
            f"{len(stds)} impacts) contains:</p><ul>" + "".join(f"<li>{e(c)}</li>" for c in contains) + "</ul>"
            f"<p>{e(scale_text)}</p><p>{e(not_in)}</p><p>{plate}.</p></section>")


# ---------------------------------------------------------------- which D
def discrepancy_measures_html(results: Mapping[str, Any]) -> str:
    """One sentence saying which deviation D the page quotes where (the discrepancy figure shows the quoted one)."""
    disc = results.get("discrepancy") or {}
    if disc.get("baseline_deviation") is None:
        return ""
    sim = results.get("simulation") or {}
    paper = ""
    if disc.get("paper_baseline_deviation") is not None:
        paper = (f"; the paper's free-running D of the whole take with the model's constant COR is "
                 f"{percent(disc.get('paper_baseline_deviation'))} → {percent(disc.get('paper_final_deviation'))}, "
                 "which per-impact COR scatter keeps at a few % whatever the model")
    return ('<p id="which-d">Which D is which: the summary, the findings, this section and the discrepancy figure '
            f"quote D = D<sub>r</sub>, Eq. 18 with each flight restarted from its measured post-impact state "
            f"({percent(disc.get('baseline_deviation'))} → {percent(disc.get('final_deviation'))}){html.escape(paper)}"
            f"; the simulation table's D is a free-running replay with each impact's measured COR (COR model "
            f"{percent(_get(sim, 'cor_model', 'deviation'))}, Hertz model "
            f"{percent(_get(sim, 'hertz_model', 'deviation'))}).</p>")
