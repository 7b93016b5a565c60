"""Scoring against a synthetic recording's truth file (for ``vibro prove``, the benchmark and tests).

The analysis never reads the truth: only :mod:`.prove` and the tests call these functions, after the
analysis has written its results.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Mapping

import numpy as np

from vibro_discrepancy.data import Measured
from vibro_discrepancy.fitting import CorModelFit, fit_flights, fit_structure_harmonics, recompute_impacts
from vibro_discrepancy.library import FLIGHT_TERMS
from vibro_discrepancy.model import FittedModel
from vibro_discrepancy.runs import full_run, restarted_run
from vibro_model.kinematics import StructureKinematics
from vibro_model.units import mm_to_m
from vibro_sim.cor_model import simulate_cor
from vibro_sim.deviation import deviation
from vibro_sim.params import BallCavity
from vibro_sim.synth.scenario import BASELINE_COR, effect_laws

# effect -> its main parameter (scored against the 15 % goal)
MAIN_PARAMETER = {"coulomb_friction": "force_n", "viscous_drag": "coefficient_ns_per_m",
                  "quadratic_drag": "coefficient_ns2_per_m2", "asymmetric_restitution": "cor_top",
                  "velocity_dependent_restitution": "slope_s_per_m", "gravity_tilt": "tilt_deg",
                  "structure_harmonics": "h2_ratio"}


def true_effects(truth: Mapping[str, Any]) -> dict[str, dict[str, float]]:
    """{effect: parameters} of a truth mapping ('none' dropped)."""
    return {e["effect"]: dict(e.get("parameters", {})) for e in truth.get("effects", []) if e["effect"] != "none"}


def main_parameter(effect: str, params: Mapping[str, float]) -> str:
    """The parameter scored for ``effect`` (harmonics: the larger ratio)."""
    if effect == "structure_harmonics" and params.get("h2_ratio", 0.0) < params.get("h3_ratio", 0.0):
        return "h3_ratio"
    return MAIN_PARAMETER[effect]


def true_structure(truth: Mapping[str, Any]) -> StructureKinematics:
    """The truth's structure motion (m, s) in the DIC frame: displacement since frame 0."""
    S = StructureKinematics.from_mm(truth["structure"])
    return replace(S, offset_m=S.offset_m - mm_to_m(float(truth["frames"]["structure_mm"][0])))


def true_model_run(meas: Measured, truth: Mapping[str, Any], t0_s: float, t_end_s: float | None = None):
    """(t, simulated ball mm since frame 0, D): the true model (truth effects and parameters without
    random COR scatter, true structure, free play and ball offset) simulated from the true state after
    the truth impact nearest ``t0_s`` and scored against the measured ball track over the same window."""
    eff = true_effects(truth)
    S = true_structure(truth)
    b = float(truth["free_play_mm"]) * 1e-3
    c0 = float(truth["ball_offset_mm"]) * 1e-3
    cav = BallCavity(mass_kg=float(truth.get("ball_mass_kg", meas.mass_kg)), free_play_m=b,
                     tilt_deg=eff.get("gravity_tilt", {}).get("tilt_deg", 0.0))
    law, force = effect_laws(eff)  # without the random COR scatter
    imps = truth["impacts"]
    if not imps:
        raise ValueError("truth has no impacts")
    j = int(np.argmin([abs(i["t"] - t0_s) for i in imps]))
    ti = float(imps[j]["t"])
    side = 1.0 if imps[j]["plate"] == "top" else -1.0
    y0 = float(S.position(ti)) + side * b * (1 - 1e-9)
    t_end = meas.t_last_s if t_end_s is None else t_end_s
    res = simulate_cor(S, cav, law, force, y0_m=y0, v0_mps=float(imps[j]["v_ball_after"]), t0_s=ti, t_end_s=t_end)
    keep = (meas.t_s >= ti) & (meas.t_s <= t_end)
    t = meas.t_s[keep]
    sim = np.asarray(res.sample(t), dtype=float) - c0
    return t, sim * 1e3, float(deviation(t, sim, meas.ball_m[keep]))


def true_fitted_model(meas: Measured, truth: Mapping[str, Any]):
    """The true model (laws and parameters of the truth, COR scatter left out, true structure motion in
    the DIC frame) with the flight states and plate levels measured from the recording the same way the
    analysis measures them: each flight fitted with the true force law (coefficients fixed)."""
    eff = true_effects(truth)
    S = true_structure(truth)
    g = float(truth.get("gravity_ms2", meas.g_mps2))
    values = {}
    if "coulomb_friction" in eff:
        values["coulomb_friction"] = eff["coulomb_friction"]["force_n"]
    if "viscous_drag" in eff:
        values["viscous_drag"] = eff["viscous_drag"]["coefficient_ns_per_m"]
    if "quadratic_drag" in eff:
        values["quadratic_drag"] = eff["quadratic_drag"]["coefficient_ns2_per_m2"]
    if "gravity_tilt" in eff:
        values["gravity_tilt"] = g * (1.0 - math.cos(math.radians(eff["gravity_tilt"]["tilt_deg"])))
    terms = tuple(t for t in FLIGHT_TERMS if t.effect in values)
    flights = fit_flights(meas, terms, g_mps2=g, fixed_coefs=[values[t.effect] for t in terms]) if terms else \
        fit_flights(meas, g_mps2=g)
    if "asymmetric_restitution" in eff:
        kind = "asymmetric_restitution"
        coefs = [eff[kind]["cor_top"], eff[kind]["cor_bottom"]]
    elif "velocity_dependent_restitution" in eff:
        kind = "velocity_dependent_restitution"
        coefs = [eff[kind]["cor_at_zero"], eff[kind]["slope_s_per_m"]]
    else:
        kind, coefs = "none", [float(truth.get("baseline", {}).get("cor", BASELINE_COR))]
    c = np.asarray(coefs, dtype=float)
    cor = CorModelFit(kind=kind, coefs=c, cov=np.zeros((c.size, c.size)), sse=0.0, n=0, dof=1, residual=np.zeros(0))
    structure = fit_structure_harmonics(meas.t_s, meas.structure_m, meas.frequency_hz, (1,))  # unused: motion fixed
    return FittedModel(structure=structure, flights=flights, impacts=recompute_impacts(meas, flights, S), cor=cor,
                       g_mps2=g, fixed_motion=S)


def true_model_measured_run(meas: Measured, truth: Mapping[str, Any]):
    """Full run of :func:`true_fitted_model` exactly as the analysis replays its own model: D of the true
    model on the same noisy data (the goal's reference)."""
    return full_run(meas, true_fitted_model(meas, truth))


UNEXPLAINED = "unexplained"


def out_of_catalogue(truth: Mapping[str, Any]) -> set[str]:
    """The truth's effects that no catalogue term models (``out_of_catalogue: true``): the analysis must
    report them as ``unexplained``."""
    return {e["effect"] for e in truth.get("effects", []) if e.get("out_of_catalogue")}


def expected_findings(truth: Mapping[str, Any]) -> set[str]:
    """What a correct analysis reports: each catalogue effect by name, ``unexplained`` for anything else."""
    true = set(true_effects(truth))
    inv = out_of_catalogue(truth)
    return (true - inv) | ({UNEXPLAINED} if inv else set())


def located_right(finding: Mapping[str, Any], effect: str, truth: Mapping[str, Any]) -> bool:
    """Whether an ``unexplained`` finding's mismatches place the invented ``effect`` where the truth has
    it: ``cor_drift`` a COR trend of the drift's sign; ``structure_tone`` a periodic structure mismatch
    within half a periodogram bin (1 / 2T, T the span tested) of the tone's frequency; ``plate_step`` a
    step of the top plate's contact level whose bracketing impacts hold the true step time; ``plate_creep`` a
    trend of the top plate's contact level of the creep's sign and its travel over the span within half;
    ``cor_parity`` the
    lower plate's COR alternating (a ``parity`` COR mismatch on the bottom plate; which impact the analysis
    counts first is its own, so the jump's size within half of the true |cor_even - cor_odd|, its sign free);
    ``position_force`` a structured flight shape (``shape``) pulling towards the lower plate, strongest nearest to
    it, independent of the direction of motion."""
    params = true_effects(truth).get(effect, {})
    if effect == "position_force":
        sh = finding.get("shape") or {}
        acc = sh.get("accel_even_mps2") or []
        return bool(sh.get("structured") and acc and acc[0] < 0 and abs(acc[0]) >= abs(acc[-1])
                    and not sh.get("direction_dependent"))
    for m in finding.get("mismatches") or []:
        span = float(m.get("t_to_s") or 0.0) - float(m.get("t_from_s") or 0.0)
        if effect == "cor_drift" and m.get("series") == "cor" and m.get("shape") == "trend":
            if np.sign(m.get("size") or 0.0) == np.sign(params.get("drift_per_s", 0.0)):
                return True
        elif effect == "structure_tone" and m.get("series") == "structure" and m.get("shape") == "periodic":
            f = m.get("frequency_hz")
            if f is not None and span > 0 and abs(f - params["tone_frequency_hz"]) < 0.5 / span:
                return True
        elif effect == "cor_parity" and m.get("series") == "cor" and m.get("shape") == "parity":
            true_jump = abs(params.get("cor_even", 0.0) - params.get("cor_odd", 0.0))
            if m.get("plate") == "bottom" and abs(abs(m.get("size") or 0.0) - true_jump) <= 0.5 * true_jump:
                return True
        elif (effect == "plate_step" and m.get("series") == "contact_level" and m.get("plate") == "top"
              and m.get("shape") == "step"):
            lo, hi = (m.get("step_between_s") or [None, None])[:2]
            if lo is not None and hi is not None and lo <= params["step_time_s"] <= hi:
                return True
        elif (effect == "plate_creep" and m.get("series") == "contact_level" and m.get("plate") == "top"
              and m.get("shape") == "trend" and span > 0):
            travel = params.get("creep_um_per_s", 0.0) * span
            size = float(m.get("size") or 0.0)
            if np.sign(size) == np.sign(travel) and abs(abs(size) - abs(travel)) <= 0.5 * abs(travel):
                return True
    return False


def score_case(doc: Mapping[str, Any], truth: Mapping[str, Any]) -> dict:
    """Compare one ``discrepancy`` block with the truth: which effects were found, missed, spurious;
    relative error of each found effect's main parameter. An out-of-catalogue effect is found when an
    ``unexplained`` finding says where (non-empty ``where``); ``located`` says whether its mismatches sit
    where the truth has the effect (:func:`located_right`). Anything reported beyond
    :func:`expected_findings` is spurious (``unexplained`` included)."""
    true = true_effects(truth)
    inv = out_of_catalogue(truth)
    found = {f["effect"]: f.get("parameters", {}) for f in doc.get("findings", [])}
    unexplained = [f for f in doc.get("findings", [])
                   if f["effect"] == UNEXPLAINED and str(f.get("where") or "").strip()]
    out = {"true": sorted(true), "found": sorted(found), "correct": [], "missed": [], "spurious": [],
           "parameter_errors": {}, "located": {}}
    for name, params in true.items():
        if name in inv:
            if unexplained:
                out["correct"].append(name)
                out["located"][name] = any(located_right(f, name, truth) for f in unexplained)
            else:
                out["missed"].append(name)
        elif name in found:
            out["correct"].append(name)
            key = main_parameter(name, params)
            tv, fv = params.get(key), found[name].get(key)
            if tv is not None and fv is not None and tv != 0:
                out["parameter_errors"][name] = {"parameter": key, "true": tv, "found": fv,
                                                 "relative_error": abs(fv - tv) / abs(tv)}
        else:
            out["missed"].append(name)
    out["spurious"] = sorted(set(found) - expected_findings(truth))
    out["exact"] = not out["missed"] and not out["spurious"]
    return out


#: a measured impact is the truth's impact of the same plate nearest in time, if within one frame (s)
MATCH_IMPACT_S = 1e-3


def cor_errors(impacts: list[Mapping[str, Any]], truth: Mapping[str, Any], match_s: float = MATCH_IMPACT_S) -> dict:
    """Per-impact COR error against the truth's realised COR (scatter included): each measured impact
    (results.json ``impacts[]`` with a COR) matched to the truth impact of the same plate nearest in time
    within ``match_s``. ``max_abs``/``median_abs`` for ``cor`` (the final model's), ``*_paper`` for
    ``cor_paper`` (the paper's Eq. 16; equal to ``cor`` when the impact was not re-identified);
    ``unmatched``: measured impacts without a truth impact (a false or misplaced impact)."""
    tt = np.array([float(i["t"]) for i in truth.get("impacts", [])])
    plates = [i["plate"] for i in truth.get("impacts", [])]
    err, err_p, worst = [], [], None
    unmatched = 0
    for imp in impacts:
        if imp.get("cor") is None or imp.get("t") is None:
            continue
        same = [k for k in np.argsort(np.abs(tt - float(imp["t"])))[:3] if plates[k] == imp["plate"]]
        if not same or abs(tt[same[0]] - float(imp["t"])) > match_s:
            unmatched += 1
            continue
        cor_true = float(truth["impacts"][same[0]]["cor"])
        paper = imp.get("cor_paper")
        e = abs(float(imp["cor"]) - cor_true)
        err.append(e)
        err_p.append(abs(float(paper if paper is not None else imp["cor"]) - cor_true))
        if worst is None or e > worst[0]:
            worst = (e, float(imp["t"]), imp["plate"])
    a, p = np.array(err), np.array(err_p)
    return {"n": int(a.size), "unmatched": unmatched,
            "max_abs": float(a.max()) if a.size else None, "median_abs": float(np.median(a)) if a.size else None,
            "max_abs_paper": float(p.max()) if p.size else None,
            "median_abs_paper": float(np.median(p)) if p.size else None,
            "worst": {"error": worst[0], "t_s": worst[1], "plate": worst[2]} if worst else None}


#: COR laws: the restarted run restarts from the measured state after every impact, so a COR law cannot
#: move D_r; its evidence is the share of the per-impact COR variance it explains
COR_LAWS = {"asymmetric_restitution": 2, "velocity_dependent_restitution": 2}   # parameters of the law


def chance_variance_share(n_parameters: int, n_impacts: int) -> float:
    """The share of the COR variance a law with ``n_parameters`` (against the constant COR's one) explains
    on pure noise, in expectation: (p - 1) / (n - 1) (the expected R^2 of p - 1 regressors on n samples)."""
    return (n_parameters - 1) / max(n_impacts - 1, 1)


def finding_deviations(doc: Mapping[str, Any], truth: Mapping[str, Any], n_impacts: int | None = None) -> list[dict]:
    """Each finding's restarted deviation D_r before/after (``deviation_*``) and the paper's D
    (``paper_deviation_*``), whether it is a correct finding and whether it improved the model:
    ``lowered`` is D_r after < before for structure and flight findings; for a COR law (D_r does not see
    it) its ``cor_variance_share`` above what chance gives on ``n_impacts`` CORs
    (:func:`chance_variance_share`). ``unexplained`` has no model, ``lowered`` None, unless it modelled
    what it located: a structure tone (its ``model`` key) or a plate's measured creep replayed (its
    ``plate_motion`` key), which D_r judges as a structure finding, or a shape
    (its ``shape_model``, :mod:`vibro_discrepancy.shape_model`): judged by the shape model's own measure (D_r
    for a position force, D_i for a COR parity), ``lowered`` when every part was accepted (its D fell)."""
    expected = expected_findings(truth)
    out = []
    for f in doc.get("findings", []):
        b, a = f.get("deviation_before"), f.get("deviation_after")
        row = {"effect": f["effect"], "correct": f["effect"] in expected, "before": b, "after": a,
               "paper_before": f.get("paper_deviation_before"), "paper_after": f.get("paper_deviation_after"),
               "lowered": None if b is None or a is None else bool(a < b), "measure": "D_r"}
        if f["effect"] in COR_LAWS:
            share = f.get("cor_variance_share")
            chance = chance_variance_share(COR_LAWS[f["effect"]], n_impacts) if n_impacts else None
            row.update(measure="cor_variance_share", cor_variance_share=share, chance_share=chance,
                       lowered=None if share is None or chance is None else bool(share > chance))
        elif f["effect"] == UNEXPLAINED and f.get("shape_model"):
            sm = f["shape_model"]
            parts = sm.get("parts") or [sm]
            row.update(measure="+".join(p["deviation"]["measure"] for p in parts),
                       shape_before=parts[0]["deviation"]["before"], shape_after=parts[-1]["deviation"]["after"],
                       lowered=all(bool(p.get("accepted")) for p in parts))
        elif f["effect"] == UNEXPLAINED and not f.get("model") and not f.get("plate_motion"):
            row.update(lowered=None, measure=None)
        out.append(row)
    return out


def shape_fit_vs_truth(finding: Mapping[str, Any] | None, truth: Mapping[str, Any]) -> dict | None:
    """An ``unexplained`` finding's ``shape_model`` parameters against the truth's out-of-catalogue effect:
    ``position_force`` its weight fraction and decay (mm), ``cor_parity`` the lower plate's two CORs (which of
    the two the analysis counts first is its own: the pairs are compared sorted); per parameter the fit, its
    std, the truth, the error and the error in stds. None without a shape model or such an effect."""
    sm = (finding or {}).get("shape_model")
    if not sm:
        return None
    eff = true_effects(truth)
    p, sd = sm.get("parameters") or {}, sm.get("parameters_std") or {}
    rows: dict[str, dict] = {}

    def row(name, fit, std, true):
        if fit is None or true is None:
            return
        err = float(fit) - float(true)
        rows[name] = {"fit": fit, "std": std, "true": true, "error": err,
                      "error_x_std": abs(err) / std if std else None}

    if "position_force" in eff:
        t = eff["position_force"]
        row("weight_fraction", p.get("weight_fraction"), sd.get("weight_fraction"), t.get("weight_fraction"))
        row("decay_mm", p.get("decay_mm"), sd.get("decay_mm"), t.get("decay_mm"))
    if "cor_parity" in eff:
        t = eff["cor_parity"]
        fit = sorted((p.get("cor_bottom_first"), p.get("cor_bottom_second")),
                     key=lambda x: -math.inf if x is None else x)
        std = {p.get("cor_bottom_first"): sd.get("cor_bottom_first"),
               p.get("cor_bottom_second"): sd.get("cor_bottom_second")}
        true = sorted((t.get("cor_even"), t.get("cor_odd")))
        for name, f, tv in zip(("cor_low", "cor_high"), fit, true):
            row(name, f, std.get(f), tv)
    if not rows:
        return None
    return {"kind": sm.get("kind"), "accepted": sm.get("accepted"), "parameters": rows}


def relative(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or not math.isfinite(a) or not math.isfinite(b) or b == 0:
        return None
    return a / b


def true_model_restarted_run(meas: Measured, truth: Mapping[str, Any]):
    """Restarted run (D_r) of :func:`true_fitted_model`, exactly as the analysis scores its own model
    (:func:`vibro_discrepancy.engine.restarted_run`): the D_r the true model reaches on the data."""
    return restarted_run(meas, true_fitted_model(meas, truth))
