"""One line per discrepancy finding, the same in ``vibro analyze``, ``vibro results`` and ``vibro graph``.

``finding: coulomb_friction force_n = 0.0001502 +- 7.3e-08; D 0.379 % -> 0.00599 %``: the effect, its
main (first) parameter with its 1-sigma where the analysis gives one, and the deviation D before and
after the effect is modelled. The report reads the same finding as a sentence in words and units
(:func:`finding_sentence`): ``The model leaves out Coulomb friction (friction force 0.150164 ± 0.000073 mN);
with it, D falls from 0.379 % to 0.00599 %.``
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping


def _value(value: float, sigma: float | None) -> str:
    if sigma is None or not math.isfinite(sigma) or sigma <= 0:
        return f"{value:.4g}"
    return f"{value:.4g} +- {sigma:.2g}"


def finding_line(effect: str, parameters: Mapping[str, float], sigmas: Mapping[str, float] | None,
                 deviation_before: float, deviation_after: float) -> str:
    """``finding: <effect> <name> = <value> +- <sigma>; D <before> % -> <after> %`` (D as percentages)."""
    main = ""
    if parameters:
        name, value = next(iter(parameters.items()))
        main = f" {name} = {_value(float(value), (sigmas or {}).get(name))}"
    return f"finding: {effect}{main}; D {100 * deviation_before:.3g} % -> {100 * deviation_after:.3g} %"


def shape_model_line(shape_model: Mapping[str, Any]) -> str:
    """``  shape modelled (<kind>): <name> = <value> +- <sigma>, ...; <measure> <before> % -> <after> %`` for an
    ``unexplained`` finding's ``shape_model`` (not a catalogue effect; ``not kept`` when its D did not fall)."""
    p, sd = shape_model.get("parameters") or {}, shape_model.get("parameters_std") or {}
    names = [k for k in ("weight_fraction", "decay_mm", "cor_bottom_first", "cor_bottom_second", "cor_top_first",
                         "cor_top_second") if k in p] or list(p)
    values = ", ".join(f"{k} = {_value(float(p[k]), sd.get(k))}" for k in names if p[k] is not None)
    dev = shape_model.get("deviation") or {}
    b, a = dev.get("before"), dev.get("after")
    d = f"; {dev.get('measure', 'D')} {percent(b)} -> {percent(a)}" if dev else ""
    kept = ("" if shape_model.get("accepted") else
            " (not kept: the form is not the residual's shape)" if shape_model.get("rejected") else
            " (not kept: D did not fall)")
    return f"  shape modelled ({shape_model.get('kind', '?')}): {values}{d}{kept}"


def findings_lines(discrepancy: Mapping[str, Any] | None) -> list[str]:
    """The lines of results.json's ``discrepancy`` section (``findings: none`` when the analysis ran and found
    nothing; ``findings: not analysed: <why>`` when it was skipped, e.g. no impacts, or failed: never "none" for
    an analysis that did not run); an ``unexplained`` finding whose shape was modelled gets a second line
    (:func:`shape_model_line`), a tilt that the scale's uncertainty could make one that says so, a mismatch the
    camera's lens explains (:mod:`vibro_discrepancy.optics`) one that names the remedy."""
    if not discrepancy:
        return ["findings: no discrepancy analysis in these results"]
    why = discrepancy.get("skipped") or discrepancy.get("error")
    if why and not discrepancy.get("findings"):
        return [f"findings: not analysed: {why}"]
    findings: Iterable[Mapping[str, Any]] = discrepancy.get("findings") or []
    lines = []
    for f in findings:
        lines.append(finding_line(f["effect"], f.get("parameters") or {}, f.get("parameters_std"),
                                  f["deviation_before"], f["deviation_after"]))
        if f.get("shape_model"):
            lines.append(shape_model_line(f["shape_model"]))
        if (f.get("plate_motion") or {}).get("plates"):
            rates = f["plate_motion"].get("mean_rate_um_per_s") or {}
            lines.append("  a plate moves against the structure: " + ", ".join(
                f"{p} {value_pm(rates.get(p), None, 'um/s')}" for p in f["plate_motion"]["plates"])
                + " (measured from the contact levels), replayed in the simulation")
        if f.get("scale_could_explain"):
            lines.append(f"  {f['scale_note']}")
        if f.get("probable_cause") == "lens_distortion":
            lens = f.get("lens") or {}
            lines.append("  probably the camera's lens, not physics"
                         + (f" (also taken for: {', '.join(f['not_claimed'])})" if f.get("not_claimed") else "")
                         + f": {lens.get('remedy', 'calibrate the camera')}")
    return lines or ["findings: none (the model explains the recording within its noise)"]


#: what an effect is called in words (docs/recording-format.md, "Effect names")
EFFECT_LABELS = {
    "coulomb_friction": "Coulomb friction", "viscous_drag": "viscous drag", "quadratic_drag": "quadratic drag",
    "asymmetric_restitution": "asymmetric restitution",
    "velocity_dependent_restitution": "velocity-dependent restitution", "gravity_tilt": "a tilted axis",
    "structure_harmonics": "structure harmonics", "unexplained": "an unexplained mismatch", "none": "nothing",
    # the shape models of an unexplained finding (vibro_discrepancy.shape_model) in a model's label
    "position_force_shape": "a position-dependent force (shape model)",
    "cor_parity_shape": "a COR alternating with the impact parity (shape model)",
}

#: a parameter's words, the unit it is shown in, and the factor from its SI value to that unit
PARAMETER_LABELS: dict[str, tuple[str, str, float]] = {
    "force_n": ("friction force", "mN", 1e3),
    "coefficient_ns_per_m": ("drag coefficient", "mN s/m", 1e3),
    "coefficient_ns2_per_m2": ("drag coefficient", "mN s²/m²", 1e3),
    "cor": ("COR", "", 1.0), "cor_top": ("COR top", "", 1.0), "cor_bottom": ("COR bottom", "", 1.0),
    "cor_at_zero": ("COR at zero speed", "", 1.0), "slope_s_per_m": ("COR slope", "s/m", 1.0),
    "tilt_deg": ("tilt", "°", 1.0),
    "h2_ratio": ("2nd harmonic ratio", "", 1.0), "h3_ratio": ("3rd harmonic ratio", "", 1.0),
    "tone_frequency_hz": ("tone frequency", "Hz", 1.0), "tone_amplitude_um": ("tone amplitude", "µm", 1.0),
    "tone_phase_rad": ("tone phase", "rad", 1.0),
    # an unexplained finding's shape model (its shape_model.parameters)
    "accel_at_contact_mps2": ("acceleration at contact", "m/s²", 1.0),
    "force_at_contact_n": ("force at contact", "µN", 1e6),
    "weight_fraction": ("share of the weight at contact", "%", 100.0),
    "decay_mm": ("decay length", "mm", 1.0),
    "cor_bottom_first": ("lower plate COR (first of the alternation)", "", 1.0),
    "cor_bottom_second": ("lower plate COR (second of the alternation)", "", 1.0),
    "cor_top_first": ("upper plate COR (first of the alternation)", "", 1.0),
    "cor_top_second": ("upper plate COR (second of the alternation)", "", 1.0),
}


def effect_label(effect: str) -> str:
    """An effect's name in words (``coulomb_friction`` -> ``Coulomb friction``; a '+'-joined pair -> 'a and b')."""
    names = [e.strip() for e in str(effect).split("+")]
    return " and ".join(EFFECT_LABELS.get(e, e.replace("_", " ")) for e in names)


def value_pm(value: float | None, sigma: float | None = None, unit: str = "") -> str:
    """``value ± sigma unit`` rounded as a measurement is: sigma to 2 significant digits, the value to the same
    decimal place (``0.700 ± 0.015``, ``1.4130485 ± 0.0000068 mm``); without a usable sigma, 4 significant
    digits."""
    tail = f" {unit}" if unit else ""
    if value is None or not math.isfinite(value):
        return "n/a"
    if sigma is None or not math.isfinite(sigma) or sigma <= 0:
        return f"{value:.4g}{tail}"
    decimals = max(0, 1 - math.floor(math.log10(sigma)))
    if decimals > 12:  # a sigma far below the value's own rounding: both in significant digits
        return f"{value:.6g} ± {sigma:.2g}{tail}"
    return f"{value:.{decimals}f} ± {sigma:.{decimals}f}{tail}"


def parameter_text(name: str, value: float, sigma: float | None = None) -> str:
    """One parameter in words and its display unit: ``friction force 0.150164 ± 0.000073 mN``."""
    label, unit, scale = PARAMETER_LABELS.get(name, (name.replace("_", " "), "", 1.0))
    return f"{label} {value_pm(scale * value, None if sigma is None else scale * sigma, unit)}"


def percent(d: float | None) -> str:
    """A deviation D as the findings lines print it (3 significant digits, %)."""
    return "n/a" if d is None else f"{100 * d:.3g} %"


#: the one-step residuals (results.json ``one_step_before``/``one_step_after``): words, unit, factor from the key's
ONE_STEP_LABELS = {"flight_rms_mm": ("the flights' residual (rms)", "µm", 1e3),
                   "impact_cor_rms": ("the impacts' COR residual (rms)", "", 1.0),
                   "impact_velocity_rms_mps": ("the impact velocity residual (rms)", "m/s", 1.0),
                   "impact_time_rms_ms": ("the impact time residual (rms)", "ms", 1.0)}


def _one_step_evidence(finding: Mapping[str, Any]) -> str:
    """The one-step residual the effect lowers most (relative), as ``<words> falls from <a> to <b> <unit>``."""
    before, after = finding.get("one_step_before") or {}, finding.get("one_step_after") or {}
    best, drop = None, 0.0
    for key in ONE_STEP_LABELS:
        b, a = before.get(key), after.get(key)
        if b and a is not None and b > 0 and 1 - a / b > drop:
            best, drop = key, 1 - a / b
    if best is None or drop < 0.05:
        return ""
    words, unit, scale = ONE_STEP_LABELS[best]
    tail = f" {unit}" if unit else ""
    return f"{words} falls from {scale * before[best]:.3g} to {scale * after[best]:.3g}{tail}"


def finding_sentence(finding: Mapping[str, Any]) -> str:
    """One finding of results.json's ``discrepancy.findings`` as a sentence with its evidence: D before and after
    it is modelled, and where D does not change (a COR law: the replay uses each impact's measured COR) the
    one-step residual it lowers; its parameters in words and units."""
    stds = finding.get("parameters_std") or {}
    params = ", ".join(parameter_text(k, float(v), stds.get(k)) for k, v in (finding.get("parameters") or {}).items())
    effect = str(finding.get("effect", "?"))
    before, after = finding.get("deviation_before"), finding.get("deviation_after")
    if percent(before) == percent(after):
        evidence = _one_step_evidence(finding)
        d = f"D stays at {percent(before)}" + (f" and {evidence}" if evidence else "")
    else:
        d = f"D {'falls' if after < before else 'goes'} from {percent(before)} to {percent(after)}"
    sm = finding.get("shape_model") if effect == "unexplained" else None
    if sm and sm.get("accepted"):   # a shape fitted but not kept: the finding reads as before (its 'where' says why)
        sstd = sm.get("parameters_std") or {}
        sparams = ", ".join(parameter_text(k, float(v), sstd.get(k)) for k, v in (sm.get("parameters") or {}).items()
                            if k in PARAMETER_LABELS and v is not None)
        dev = sm.get("deviation") or {}
        measure = " (D through the impacts, with the model's COR)" if dev.get("measure") == "D_i" else ""
        return (f"A mismatch no catalogued effect accounts for remains: its shape, modelled as {sm.get('form', '?')} "
                f"({sparams}), is not a catalogue effect; with it, D{measure} falls from {percent(dev.get('before'))} "
                f"to {percent(dev.get('after'))}.")
    plates = (finding.get("plate_motion") or {}) if effect == "unexplained" else {}
    if plates.get("plates") and not params:
        rates = plates.get("mean_rate_um_per_s") or {}
        moved = " and ".join(f"the {p} plate ({value_pm(rates.get(p), None, 'µm/s')})" for p in plates["plates"])
        return (f"A plate moves against the tracked structure, which no catalogued effect names: {moved}, measured "
                f"from where the ball meets it; with its motion replayed, {d}.")
    if effect == "unexplained" and not params:
        return f"A mismatch no modelled effect accounts for remains; {d}."
    what = "a structure tone no catalogued effect names" if effect == "unexplained" else effect_label(effect)
    if finding.get("in_final_model") is False:   # dropped beside a modelled shape (shape_model of unexplained)
        return (f"{what[:1].upper() + what[1:]}" + (f" ({params})" if params else "")
                + f" lowers the catalogue model's deviation ({d}) but is not in the final model: with the "
                "unexplained shape modelled, the data do not need it.")
    return f"The model leaves out {what}" + (f" ({params})" if params else "") + f"; with it, {d}."
