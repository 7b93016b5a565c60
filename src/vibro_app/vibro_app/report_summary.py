"""The report's opening summary, read in ten seconds: recording, regime, COR per plate, the finding, completeness.

:func:`summary_html` is a ``<section id="summary">`` holding one table whose rows carry a stable
``data-key`` (``recording``, ``excitation``, ``regime``, ``cor.<plate>``, ``finding.<k>`` or ``finding``,
``complete``, ``warnings``): labels and values in words and units, values as ``value ± sigma`` rounded as a
measurement is (:func:`vibro_app.findings_text.value_pm`), the findings as the sentences of
:func:`vibro_app.findings_text.finding_sentence`. The detail tables of :mod:`vibro_app.report` use the same
formatting (:func:`structure_rows`, :func:`simulation_rows`).
"""

from __future__ import annotations

import html
import re
from typing import Any, Mapping

from vibro_app.findings_text import effect_label, finding_sentence, percent, value_pm

#: a warning that says what a run lost: shown with the completeness, not again among the warnings
LOSS = re.compile(r"cut short|\blost\b|missing|not reported", re.IGNORECASE)

#: the structure's sine (Eq. 2): (label, value key, sigma key, unit)
STRUCTURE_QUANTITIES = (("amplitude", "amplitude_mm", "amplitude_std_mm", "mm"),
                        ("frequency", "frequency_hz", "frequency_std_hz", "Hz"),
                        ("phase", "phase_rad", "phase_std_rad", "rad"),
                        ("offset", "offset_mm", "offset_std_mm", "mm"))

#: the simulated models of results.json's ``simulation`` in words
MODEL_LABELS = {"cor_model": "COR model (the measured COR at each impact)",
                "hertz_model": "Hertz contact model (damped Hertz contact at each impact)"}


def _words(name: Any) -> str:
    return str(name).replace("_", " ")


def structure_rows(structure: Mapping[str, Any] | None) -> list[tuple[str, str]]:
    """(label, value with unit) rows of results.json's ``structure`` section."""
    s = structure or {}
    if not s:
        return [("structure", "not identified")]
    rows = [(label, value_pm(s.get(key), s.get(std), unit)) for label, key, std, unit in STRUCTURE_QUANTITIES
            if s.get(key) is not None]
    if s.get("rms_residual_mm") is not None:
        rows.append(("fit residual (rms)", f"{1e3 * s['rms_residual_mm']:.3g} µm"))
    if s.get("n_points") is not None:
        rows.append(("frames fitted", f"{s['n_points']}"))
    if s.get("ball_offset_mm") is not None:
        rows.append(("ball centre from the cavity centre at frame 0 (+ up)", f"{s['ball_offset_mm']:.4f} mm"))
    if "moving" in s:
        rows.append(("structure moves", "yes" if s["moving"] else "no: its sine does not stand out of the noise"))
    if s.get("note"):
        rows.append(("note", str(s["note"])))
    return rows


def simulation_rows(simulation: Mapping[str, Any] | None) -> list[tuple[str, str]]:
    """(model in words, D) rows of results.json's ``simulation`` section."""
    return [(MODEL_LABELS.get(k, _words(k)), percent(v.get("deviation")))
            for k, v in (simulation or {}).items() if isinstance(v, Mapping)]


def cor_text(plate_summary: Mapping[str, Any]) -> str:
    """``0.700 ± 0.015 (n = 33)``: a plate's mean COR, the standard deviation of its impacts' CORs, n."""
    n = plate_summary.get("n") or 0
    if not n or plate_summary.get("mean") is None:
        return "no impact with a COR"
    return f"{value_pm(plate_summary['mean'], plate_summary.get('std'))} (n = {n})"


def _finding_rows(disc: Mapping[str, Any]) -> list[tuple[str, str, str]]:
    e = html.escape
    if disc.get("error"):
        return [("finding", "Finding", e(f"the discrepancy analysis failed: {disc['error']}"))]
    findings = disc.get("findings") or []
    if disc.get("skipped") and not findings:   # not run (no impacts, an inconsistent rig): never "none"
        return [("finding", "Finding", e(f"not analysed: {disc['skipped']}"))]
    if findings:
        label = "Finding" if len(findings) == 1 else "Findings"
        return [(f"finding.{k}", label if k == 0 else "", e(finding_sentence(f))) for k, f in enumerate(findings)]
    if disc.get("baseline_deviation") is None:
        return [("finding", "Finding", "no discrepancy analysis in these results")]
    return [("finding", "Finding", e(f"none: the model explains the recording within its noise "
                                     f"(D = {percent(disc['baseline_deviation'])})."))]


def summary_rows(results: Mapping[str, Any]) -> list[tuple[str, str, str]]:
    """(data-key, label, HTML value) rows of the summary of a results.json mapping."""
    e = html.escape
    rows = [("recording", "Recording", f"<code>{e(str(results.get('recording', '')))}</code>: "
             f"{len(results.get('flights') or [])} flights, {len(results.get('impacts') or [])} impacts")]
    s = results.get("structure") or {}
    if s.get("amplitude_mm") is not None and s.get("frequency_hz") is not None:
        amplitude = value_pm(s["amplitude_mm"], s.get("amplitude_std_mm"), "mm")
        frequency = value_pm(s["frequency_hz"], s.get("frequency_std_hz"), "Hz")
        rows.append(("excitation", "Excitation", e(f"amplitude {amplitude} at {frequency}")))
    regime = results.get("regime") or {}
    if regime.get("name"):
        cycles = regime.get("n_cycles")
        rows.append(("regime", "Regime", e(_words(regime["name"])
                                           + (f" over {cycles:.0f} excitation cycles" if cycles else ""))))
    for plate, d in (results.get("cor_summary") or {}).items():
        rows.append((f"cor.{plate}", f"COR {e(plate)} (mean ± std)", e(cor_text(d))))
    disc = results.get("discrepancy") or {}
    rows += _finding_rows(disc)
    if len(disc.get("findings") or []) > 1 and disc.get("model"):  # one finding: its sentence says it
        rows.append(("final_model", "Final model", e(f"the baseline with {effect_label(disc['model'])}: D "
                                                     f"{percent(disc.get('baseline_deviation'))} → "
                                                     f"{percent(disc.get('final_deviation'))}")))
    warnings = [str(w) for w in results.get("warnings") or []]
    lost = [w for w in warnings if LOSS.search(w)]
    complete = "complete" if results.get("complete", True) else "incomplete"
    rows.append(("complete", "Completeness", e(complete) + "".join(f"<br>{e(w)}" for w in lost)))
    others = [w for w in warnings if w not in lost]
    rows.append(("warnings", "Warnings", "<ul>" + "".join(f"<li>{e(w)}</li>" for w in others) + "</ul>"
                 if others else "none"))
    return rows


def summary_html(results: Mapping[str, Any]) -> str:
    """The ``<section id="summary">`` that opens the report (rows as :func:`summary_rows`)."""
    rows = "".join(f'<tr data-key="{html.escape(key)}"><th>{label}</th><td>{value}</td></tr>'
                   for key, label, value in summary_rows(results))
    return f'<section id="summary"><h2>Summary</h2><table class="summary">{rows}</table></section>'
