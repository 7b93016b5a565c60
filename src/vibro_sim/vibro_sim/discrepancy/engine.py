"""``analyse_discrepancy``: baseline -> locate -> explain -> model and show (issue 6).

Input: the results sections (``structure``, ``flights``, ``impacts`` as in results.json), the DIC track
and the rig. Output: the contract's ``discrepancy`` block (baseline_deviation, findings[{effect,
parameters, where, deviation_before, deviation_after}], final_deviation) plus extras: the paper's D,
parameter
uncertainties, the noise floors, the one-step errors before/after, the location of the baseline's
mismatch, every tested candidate with its statistic.

Two deviations, both on the paper's Eq. 18 scale (a fraction of the measured displacement):

- D_r, the restarted deviation (``baseline_deviation``, ``final_deviation`` and each finding's
  ``deviation_before``/``deviation_after``): every fitted flight simulated with vibro_sim's exact COR
  model from the measured state after the impact that opens it (:func:`restarted_run`). A real rig
  gives every impact its own COR; restarting after each impact keeps that scatter from accumulating,
  so D_r measures the model (flight law, structure motion), not the chaos: it falls to the noise floor
  (sigma / RMS of the ball displacement) once the model is right, whatever the COR scatter.
- D, the paper's free-running deviation (``paper_baseline_deviation``, ``paper_final_deviation``,
  ``paper_deviation_before/after``): simulated once from the measured state after the first impact
  that opens a fitted flight to the end of the track (:func:`full_run`). With per-impact COR scatter
  the replay drifts from the record within a few impacts and D stays at a few % for any model.

A COR law is judged by the per-impact CORs instead (D_r replays the measured post-impact velocities):
``cor_variance_share``, the share of the COR variance beyond the measurement noise the law explains.
The baseline: constant COR = the mean measured one, gravity only, pure sine structure, vertical. The
findings are added in order (structure, flight terms, COR law); before/after are the models
without/with each.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from vibro_io.dictrack import DicTrack
from vibro_io.rig import RigConfig
from vibro_model.codec import json_number as _num
from vibro_model.codec import json_value as jsonable

from ..cor_model import simulate_cor
from ..deviation import Restart, deviation, restarted_deviation
from .data import Measured, difference_sigma, measured_from_sections
from .fitting import fit_flights, fit_structure
from .library import FLIGHT_TERMS, IMPACT_TERMS, UNEXPLAINED, FlightTerm
from .locate import locate, structure_words
from .model import FittedModel, fit_model, plate_levels
from .onestep import OneStep, one_step
from .select import UNEXPLAINED_RATIO, law_variance_share, select_cor, select_flights, select_structure
from .systematic import contact_scatter, systematic_mismatch

log = logging.getLogger(__name__)


@dataclass
class FullRun:
    t_s: np.ndarray
    simulated_m: np.ndarray | None
    measured_m: np.ndarray
    deviation: float | None
    error: str | None = None


@dataclass
class DiscrepancyRun:
    """Everything the analysis computed: the contract document and arrays for figures."""

    document: dict
    measured: Measured | None = None
    baseline: FittedModel | None = None
    final: FittedModel | None = None
    baseline_run: FullRun | None = None
    final_run: FullRun | None = None
    baseline_steps: OneStep | None = None
    final_steps: OneStep | None = None
    chain: list[tuple[str, FittedModel, FullRun]] = field(default_factory=list)


def full_run(meas: Measured, model: FittedModel) -> FullRun:
    """Simulate ``model`` over the recording from the measured state after the first impact that opens a
    fitted flight; D against the measured ball (DIC frame)."""
    t_all, y_all = meas.t_s, meas.ball_m
    k0 = next((k for k, fl in enumerate(meas.flights) if fl.open_impact is not None), None)
    if k0 is None:
        return FullRun(t_all, None, y_all, None, "no flight opened by an impact")
    fl = meas.flights[k0]
    t_imp = dict(zip((int(i) for i in model.impacts.index), (float(t) for t in model.impacts.t_s)))
    t0 = t_imp.get(int(fl.open_impact), fl.t_ref_s)
    y_start, v_start = (float(x) for x in model.flights.state(k0, t0 - fl.t_ref_s))
    keep = t_all >= t0
    t, y = t_all[keep], y_all[keep]
    if t.size < 2:
        return FullRun(t, None, y, None, "too few frames after the first impact")
    try:
        lv = plate_levels(meas, model)
        c0, b = lv["offset"], lv["free_play"]
        S = model.motion
        rel = y_start + c0 - float(S.position(t0))
        rel = min(max(rel, -b * (1 - 1e-9)), b * (1 - 1e-9))
        res = simulate_cor(S, model.cavity(meas, b), model.restitution_law(), model.force_law(),
                           float(S.position(t0)) + rel, v_start, t0, float(t[-1]))
        sim = np.asarray(res.sample(t), dtype=float) - c0
        return FullRun(t, sim, y, float(deviation(t, sim, y)))
    except Exception as exc:  # a model that cannot be simulated must not lose the analysis
        log.warning("discrepancy full run of %s failed: %s", model.label(), exc)
        return FullRun(t, None, y, None, f"{type(exc).__name__}: {exc}")


def restart_points(meas: Measured, model: FittedModel) -> list[Restart]:
    """The measured state after each impact that opens a fitted flight, as ``model`` measures it (the
    paper's Eq. 14 with the model's flight law in place of Eq. 3): the flight's fitted position and
    velocity (DIC frame, m and m/s) at the impact time where the model's flights meet (Eq. 15 under the
    model; the identified time if the model has none for it). The window ends at the impact that closes
    the flight, else at its last fitted frame.

    Not the identified parabola (Eq. 3) at the identified time: under a speed-dependent force the
    parabola's start velocity and time are biased (the quadratic-drag case restarted from them keeps
    D_r = 0.0086 with the true law, 170x its noise floor), so the start would judge the parabola, not
    the model."""
    t_imp = dict(zip((int(i) for i in model.impacts.index), (float(t) for t in model.impacts.t_s)))
    out = []
    for k, fl in enumerate(meas.flights):
        if fl.open_impact is None:
            continue
        t0 = t_imp.get(int(fl.open_impact), float(meas.impacts[fl.open_impact].t_s))
        y0, v0 = (float(x) for x in model.flights.state(k, t0 - fl.t_ref_s))
        t1 = fl.t_end_s if fl.close_impact is not None else float(fl.t_s[-1])
        out.append(Restart(t0, t1, y0, v0))
    return out


def restarted_run(meas: Measured, model: FittedModel) -> FullRun:
    """D_r of ``model`` (:func:`vibro_sim.deviation.restarted_deviation`): each fitted flight simulated
    from the measured state after the impact that opens it (:func:`restart_points`), compared with the
    measured ball; the model's plate levels and free play as in :func:`full_run`."""
    try:
        lv = plate_levels(meas, model)
        r = restarted_deviation(meas.t_s, meas.ball_m, restart_points(meas, model), model.motion,
                                model.cavity(meas, lv["free_play"]), model.restitution_law(), model.force_law(),
                                frame_offset_m=lv["offset"])
        return FullRun(r.t_s, r.simulated_m, r.measured_m, r.deviation)
    except Exception as exc:  # a model that cannot be simulated must not lose the analysis
        log.warning("discrepancy restarted run of %s failed: %s", model.label(), exc)
        return FullRun(meas.t_s[:0], None, meas.ball_m[:0], None, f"{type(exc).__name__}: {exc}")


def _cor_noise(meas: Measured) -> float:
    stds = [i.cor_std for i in meas.impacts if i.cor_std > 0]
    return float(np.median(stds)) if stds else 0.0


def _flight_where(meas: Measured, steps: OneStep, model_after: FittedModel, term: FlightTerm,
                  cor_noise: float) -> str:
    """Where a flight term shows: the extra acceleration it adds on each kind of flight, and the
    before-model's mismatch location."""
    words = locate(steps, cor_noise, stages=("flights",))["text"]
    extra = {}
    for k, fl in enumerate(meas.flights):
        u, v = model_after.flights.grids[k]
        c = model_after.flights.coef_of(term.effect)
        a = c * term.basis(v, meas.mass_kg)
        extra.setdefault(fl.direction, []).append(float(np.mean(a)))
    parts = [f"{'towards the top plate' if d == 'up' else 'towards the bottom plate'} {np.mean(v):+.3f} m/s^2"
             for d, v in sorted(extra.items(), reverse=True)]
    return f"{words}; {term.effect} adds a mean acceleration of " + ", ".join(parts)


def _cor_where(meas: Measured, steps: OneStep, model_after: FittedModel, cor_noise: float) -> str:
    words = locate(steps, cor_noise, stages=("impacts",))["text"]
    imp = model_after.impacts
    parts = []
    for p in ("top", "bottom"):
        sel = imp.plate == p
        if sel.any():
            parts.append(f"{p}: COR {np.mean(imp.cor[sel]):.3f} +- {np.std(imp.cor[sel]):.3f} at "
                         f"{np.mean(imp.speed[sel]):.3f} m/s")
    return f"{words}; measured " + ", ".join(parts)


def run_discrepancy(sections: Mapping[str, Any], track: DicTrack, rig: RigConfig,
                    flight_terms: tuple[FlightTerm, ...] = FLIGHT_TERMS, cor_terms=("asymmetric_restitution",
                                                                                     "velocity_dependent_restitution"),
                    harmonics: bool = True) -> DiscrepancyRun:
    """The whole analysis (see the module docstring). ``flight_terms``/``cor_terms``/``harmonics``
    restrict the library (tests use this to check that an effect outside it is reported unexplained)."""
    meas = measured_from_sections(sections, track, rig)
    cor_noise = _cor_noise(meas)
    sig_f = difference_sigma([(f.t_s, f.y_m) for f in meas.flights], 3)
    sig_s = difference_sigma([(meas.t_s, meas.structure_m)], 5)
    if not math.isfinite(sig_f) or sig_f <= 0:
        sig_f = difference_sigma([(meas.t_s, meas.ball_m)], 5)
    notes = list(meas.notes)

    # baseline ---------------------------------------------------------------------------------
    base = fit_model(meas)
    base_run = full_run(meas, base)
    base_steps = one_step(meas, base, sig_f)
    where_base = locate(base_steps, cor_noise)
    s1 = fit_structure(meas.t_s, meas.structure_m, meas.frequency_hz, (1,))

    # explain: stage by stage --------------------------------------------------------------------
    if harmonics:
        s_fit, s_stage = select_structure(meas, sig_s)
    else:
        s_fit, s_stage = s1, None
    if flight_terms:
        f_fit, f_stage = select_flights(meas, sig_f, tuple(flight_terms))
    else:
        f_fit, f_stage = fit_flights(meas), None
    pre_cor = fit_model(meas, structure=s_fit, flights=f_fit)
    kind, _, c_stage = select_cor(pre_cor.impacts, cor_noise)
    if kind not in cor_terms:
        kind = "none"
        c_stage.chosen = ()

    # model and show: the chain of models, one finding at a time ----------------------------------------
    chain: list[tuple[str, FittedModel, FullRun]] = [("baseline", base, base_run)]
    restarted_chain: list[tuple[str, FullRun]] = []
    findings: list[dict] = []
    current = base
    current_run = base_run
    current_steps = base_steps

    base_restarted = restarted_run(meas, base)
    current_restarted = base_restarted

    def add(effect: str, model: FittedModel, params: dict, stds: dict, where: str, extra: dict | None = None):
        nonlocal current, current_run, current_steps, current_restarted
        run = full_run(meas, model)
        restarted = restarted_run(meas, model)
        steps = one_step(meas, model, sig_f)
        findings.append({"effect": effect, "parameters": params, "parameters_std": stds, "where": where,
                         "deviation_before": _num(current_restarted.deviation),
                         "deviation_after": _num(restarted.deviation),
                         "paper_deviation_before": _num(current_run.deviation),
                         "paper_deviation_after": _num(run.deviation),
                         "one_step_before": current_steps.summary(), "one_step_after": steps.summary(),
                         **(extra or {})})
        chain.append((effect, model, run))
        restarted_chain.append((effect, restarted))
        current, current_run, current_steps, current_restarted = model, run, steps, restarted

    if s_stage is not None and s_stage.chosen:
        m = fit_model(meas, structure=s_fit, flights=fit_flights(meas))
        mot = s_fit.motion()
        amps = s_fit.harmonic_amplitudes()
        params = {"h2_ratio": float(mot.h2_ratio), "h3_ratio": float(mot.h3_ratio)}
        sd = s_fit.sigma * math.sqrt(2.0 / s_fit.n_points) / max(mot.amplitude_m, 1e-12)
        stds = {"h2_ratio": sd if 2 in amps else None, "h3_ratio": sd if 3 in amps else None}
        where = structure_words(s1.residual, meas.t_s, sig_s, s1.frequency_hz) + "; " + \
            locate(current_steps, cor_noise, stages=("impacts",))["text"]
        add("structure_harmonics", m, params, stds, where,
            {"phases_rad": {"h2_phase_rad": float(mot.h2_phase_rad), "h3_phase_rad": float(mot.h3_phase_rad)}})
    if f_stage is not None and f_stage.chosen:
        # add the terms in the order of what each explains alone (the chain's D), parameters and their
        # uncertainties from the fit with all chosen terms
        single = {d.label: d.statistic for d in f_stage.decisions}
        chosen_terms = sorted((t for t in flight_terms if t.effect in f_stage.chosen),
                              key=lambda t: -single.get(t.effect, 0.0))
        for j, term in enumerate(chosen_terms):
            fset = f_fit if j == len(chosen_terms) - 1 else fit_flights(meas, tuple(chosen_terms[:j + 1]))
            m = fit_model(meas, structure=current.structure, flights=fset)
            idx = f_fit.names.index(term.effect)
            params, stds = term.contract_parameters(float(f_fit.coefs[idx]), float(math.sqrt(f_fit.cov[idx, idx])),
                                                    meas.mass_kg, meas.g_ms2)
            where = _flight_where(meas, current_steps, m, term, cor_noise)
            add(term.effect, m, params, stds, where)
    if kind != "none":
        m = fit_model(meas, structure=current.structure, flights=current.flights, cor_kind=kind)
        term = next(t for t in IMPACT_TERMS if t.effect == kind)
        params, stds = term.contract_parameters(m.cor.coefs, m.cor.cov)
        where = _cor_where(meas, current_steps, m, cor_noise)
        extra = {"cor_variance_share": _num(law_variance_share(m.impacts, m.cor))}
        if c_stage.alternatives:
            extra["alternatives"] = list(c_stage.alternatives)
        if c_stage.notes:
            extra["note"] = "; ".join(c_stage.notes)
        add(kind, m, params, stds, where, extra)

    # whatever is left: unexplained (systematic patterns the final model leaves; random COR scatter is not)
    final_loc = locate(current_steps, cor_noise)
    patterns = systematic_mismatch(meas, current, sig_s, sig_f, 1.0 / float(np.median(np.diff(meas.t_s))))
    leftovers = []
    s_ratio = s_stage.residual_ratio if s_stage is not None else s1.sigma / sig_s
    if s_ratio > UNEXPLAINED_RATIO and not any(p.series == "structure" for p in patterns):
        leftovers.append(structure_words(current.structure.residual, meas.t_s, sig_s, s1.frequency_hz)
                         .replace("the pure sine misses", "the model misses"))
    if f_stage is not None and f_stage.unexplained:
        leftovers.append(final_loc["words"][0] if final_loc["words"] else "flights")
    elif f_stage is None:
        ratio = math.sqrt(current.flights.sse / max(current.flights.n_points, 1)) / sig_f
        if ratio > 1.5:
            leftovers.append(final_loc["words"][0] if final_loc["words"] else "flights")
    leftovers += [p.words() for p in patterns]
    if leftovers:
        findings.append({"effect": UNEXPLAINED, "parameters": {}, "where": "; ".join(leftovers),
                         "deviation_before": _num(current_restarted.deviation),
                         "deviation_after": _num(current_restarted.deviation),
                         "paper_deviation_before": _num(current_run.deviation),
                         "paper_deviation_after": _num(current_run.deviation),
                         "mismatches": [p.to_dict() for p in patterns]})

    stages = {}
    for st in (s_stage, f_stage, c_stage):
        if st is None:
            continue
        stages[st.name] = {"chosen": list(st.chosen), "residual_x_noise": _num(st.residual_ratio),
                           "unexplained": st.unexplained, "notes": st.notes,
                           "candidates": [d.to_dict() for d in st.decisions]}
    doc = {
        "baseline_deviation": _num(base_restarted.deviation),
        "findings": findings,
        "final_deviation": _num(current_restarted.deviation),
        "paper_baseline_deviation": _num(base_run.deviation),
        "paper_final_deviation": _num(current_run.deviation),
        "model": current.label(),
        "replay_start_s": _num(base_run.t_s[0]) if base_run.t_s.size else None,
        "noise_floor": {"ball_mm_per_frame": _num(sig_f * 1e3), "structure_mm_per_frame": _num(sig_s * 1e3),
                        "cor": _num(cor_noise)},
        "cor_scatter": _num(math.sqrt(current.cor.sse / max(current.cor.dof, 1))) if current.cor.n else None,
        "contact_scatter": contact_scatter(current, patterns),
        "one_step": {"baseline": base_steps.summary(), "final": current_steps.summary()},
        "location": {k: v for k, v in where_base.items() if k != "words"},
        "stages": stages,
        "notes": notes + [f"{name}: {r.error}" for name, _, r in chain if r.error]
        + [f"{name} (restarted): {r.error}" for name, r in [("baseline", base_restarted)] + restarted_chain if r.error],
    }
    return DiscrepancyRun(jsonable(doc), meas, base, current, base_run, current_run, base_steps, current_steps, chain)


def analyse_discrepancy(results_sections: Mapping[str, Any], track: DicTrack, rig: RigConfig) -> dict:
    """The contract's ``discrepancy`` block (plus extras) for one recording; see the module docstring."""
    return run_discrepancy(results_sections, track, rig).document


def discrepancy_skip_reason(doc: Mapping[str, Any]) -> str | None:
    """Why the discrepancy analysis does not apply to a results document, or None: no impacts (nothing for
    an impact model to be compared with), or a rig description inconsistent with the measurement."""
    blocking = [r for r in (doc.get("rig_consistency") or []) if r.get("blocks_physics", True)]
    if blocking:
        keys = sorted({k for r in blocking for k in r.get("keys", [])})
        return ("discrepancy analysis skipped: the rig description is inconsistent with the measurement ("
                + ", ".join(keys) + "); no physics finding is built on it (see rig_consistency)")
    if not doc.get("impacts"):
        motion = (doc.get("motion") or {}).get("state")
        what = f" (recording: {motion.replace('_', ' ')})" if motion else ""
        return f"discrepancy analysis skipped: no impacts identified{what}, nothing to compare a model with"
    return None


def discrepancy_for_results(doc: Mapping[str, Any], track: DicTrack, rig: RigConfig
                            ) -> tuple[dict, DiscrepancyRun | None, str | None]:
    """For ``vibro analyze``: (discrepancy block, run or None, error message or None) from a results
    document. A recording the analysis cannot handle (too few flights, a model that fails) gives the
    baseline-only block with an ``error`` key instead of losing the identification. A recording without
    impacts, or whose rig description contradicts the measurement (``rig_consistency`` entries that block
    physics), is not analysed: the block carries ``skipped`` with the reason, returned as the message."""
    reason = discrepancy_skip_reason(doc)
    if reason is not None:
        d0 = (doc.get("simulation") or {}).get("cor_model", {}).get("deviation")
        return {"baseline_deviation": d0, "findings": [], "final_deviation": d0, "skipped": reason}, None, reason
    try:
        run = run_discrepancy(doc, track, rig)
        return run.document, run, None
    except Exception as exc:  # noqa: BLE001 - reported, never fatal for the identification
        log.warning("discrepancy analysis failed: %s", exc)
        d0 = (doc.get("simulation") or {}).get("cor_model", {}).get("deviation")
        msg = f"discrepancy analysis failed: {type(exc).__name__}: {exc}"
        return {"baseline_deviation": d0, "findings": [], "final_deviation": d0, "error": msg}, None, msg
