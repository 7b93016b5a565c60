"""PySINDy, the nearest existing tool, on the same measured data, scored the same way (``vibro prove``).

What SINDy gets (the same recording the engine sees, via the identification's results and dic.csv):

* flights: the ball track of every free flight; SINDy differentiates it (smoothed finite differences,
  Savitzky-Golay) to the velocity v(t) and again to the acceleration, and fits dv/dt = Theta(v) xi with a
  library of the same terms: 1 (gravity, and tilt as a change of it), sign(v) (Coulomb), v (viscous),
  v|v| (quadratic); sparse by sequentially thresholded least squares (STLSQ);
* impacts: the identified per-impact relative velocities; v_rel_after = Theta xi with Theta = [v_b,
  v_b * is_top, v_b |v_b|] (a constant COR, a top-plate change, a speed-dependent change), STLSQ;
* structure: the structure track against [1, sin k w t, cos k w t], k = 1..3, STLSQ (harmonics 2, 3).

Thresholds are SINDy's one knob; they are set once, on control recordings only (no effect), to the
smallest values that gave no finding there, as a user would calibrate (``THRESHOLDS``).
A finding is a term whose coefficient survives the threshold; parameters follow from the coefficients;
D after is the full-run D (same simulator, same initial state) of the model SINDy selected.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from vibro_discrepancy.data import Measured
from vibro_discrepancy.fitting import fit_flights, fit_structure_harmonics
from vibro_discrepancy.library import FLIGHT_TERMS
from vibro_discrepancy.model import FittedModel, fit_model
from vibro_discrepancy.runs import full_run
from vibro_model.codec import json_value as jsonable

THRESHOLDS = {"flight_mps2": 0.7, "cor": 0.11, "harmonic_m": 5e-8}  # calibrate() on 4 controls
SAVGOL = {"window_length": 7, "polyorder": 3}


def available() -> str | None:
    """Pysindy's version, or None when it is not installed."""
    try:
        import pysindy
    except ImportError:
        return None
    return getattr(pysindy, "__version__", "?")


def _stlsq(X: np.ndarray, y: np.ndarray, threshold: float) -> np.ndarray:
    import pysindy as ps

    opt = ps.STLSQ(threshold=threshold, alpha=1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opt.fit(X, y.reshape(-1, 1))
    return np.asarray(opt.coef_, dtype=float).ravel()


def sindy_flights(meas: Measured, threshold: float = THRESHOLDS["flight_mps2"]) -> dict:
    """dv/dt = xi_0 + xi_1 sign(v) + xi_2 v + xi_3 v|v| by PySINDy over all free flights."""
    import pysindy as ps

    lib = ps.CustomLibrary(library_functions=[lambda v: np.sign(v), lambda v: v, lambda v: v * np.abs(v)],
                           function_names=[lambda s: f"sign({s})", lambda s: s, lambda s: f"{s}|{s}|"],
                           include_bias=True)
    diff = ps.SmoothedFiniteDifference(smoother_kws=SAVGOL)
    vs, ts = [], []
    for fl in meas.flights:
        if fl.t_s.size < SAVGOL["window_length"] + 2:
            continue
        v = np.asarray(diff._differentiate(fl.y_m.reshape(-1, 1), fl.t_s), dtype=float)
        vs.append(v)
        ts.append(fl.t_s.copy())
    if not vs:
        return {"coefficients": None, "terms": {}}
    model = ps.SINDy(optimizer=ps.STLSQ(threshold=threshold, alpha=1e-9), feature_library=lib,
                     differentiation_method=ps.SmoothedFiniteDifference(smoother_kws=SAVGOL))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(vs, t=ts, feature_names=["v"])
    xi = np.asarray(model.coefficients(), dtype=float).ravel()   # [1, sign, v, v|v|]
    m, g = meas.mass_kg, meas.g_mps2
    terms = {}
    da = xi[0] + g
    if abs(da) > threshold and da > 0:
        terms["gravity_tilt"] = da
    if xi[1] < 0:
        terms["coulomb_friction"] = -xi[1] * m
    if xi[2] < 0:
        terms["viscous_drag"] = -xi[2] * m
    if xi[3] < 0:
        terms["quadratic_drag"] = -xi[3] * m
    return {"coefficients": xi.tolist(), "terms": terms,
            "unphysical": bool(xi[1] > 0 or xi[2] > 0 or xi[3] > 0 or (abs(da) > threshold and da < 0))}


def sindy_impacts(meas: Measured, threshold: float = THRESHOLDS["cor"]) -> dict:
    """v_rel_after = -(e0 + d_top is_top - s |v_b|) v_b: STLSQ on [v_b, v_b is_top, v_b |v_b|]."""
    rows = [(i.v_ball_before_mps - i.v_structure_mps, i.v_ball_after_mps - i.v_structure_mps, i.plate)
            for i in meas.impacts]
    if len(rows) < 4:
        return {"coefficients": None, "kind": "none", "coefs": None}
    vb = np.array([r[0] for r in rows])
    va = np.array([r[1] for r in rows])
    top = np.array([r[2] == "top" for r in rows], dtype=float)
    X = np.column_stack([vb, vb * top, vb * np.abs(vb)])
    xi = _stlsq(X, va, threshold)           # va = xi0 vb + xi1 vb top + xi2 vb |vb|, e = -(...)
    e0, d_top, s = -xi[0], -xi[1], xi[2]
    if xi[1] != 0 and xi[2] != 0:
        kind, coefs = "plate_and_speed", [e0 + d_top, e0, s]
    elif xi[1] != 0:
        kind, coefs = "asymmetric_restitution", [e0 + d_top, e0]
    elif xi[2] != 0:
        kind, coefs = "velocity_dependent_restitution", [e0, s]
    else:
        kind, coefs = "none", [e0]
    return {"coefficients": xi.tolist(), "kind": kind, "coefs": coefs}


def sindy_structure(meas: Measured, threshold: float = THRESHOLDS["harmonic_m"]) -> dict:
    """Harmonics 2 and 3 that survive STLSQ on the structure track (frequency from the identification)."""
    w = 2 * math.pi * meas.frequency_hz
    t, y = meas.t_s, meas.structure_m
    cols = [np.ones_like(t)]
    for k in (1, 2, 3):
        cols += [np.sin(k * w * t), np.cos(k * w * t)]
    xi = _stlsq(np.column_stack(cols), y, threshold)
    orders = tuple(k for j, k in enumerate((2, 3)) if xi[3 + 2 * j] != 0 or xi[4 + 2 * j] != 0)
    return {"coefficients": xi.tolist(), "orders": orders}


def sindy_discrepancy(meas: Measured) -> dict:
    """SINDy's findings in the contract's shape, with D of the baseline and of SINDy's model."""
    fl = sindy_flights(meas)
    im = sindy_impacts(meas)
    st = sindy_structure(meas)
    base = fit_model(meas)
    base_run = full_run(meas, base)
    findings = []
    if st["orders"]:
        s_fit = fit_structure_harmonics(meas.t_s, meas.structure_m, meas.frequency_hz, (1,) + st["orders"])
        mot = s_fit.motion()
        findings.append({"effect": "structure_harmonics",
                         "parameters": {"h2_ratio": mot.h2_ratio, "h3_ratio": mot.h3_ratio}})
    else:
        s_fit = base.structure
    terms = [t for t in FLIGHT_TERMS if t.effect in fl["terms"]]
    coefs = [fl["terms"][t.effect] for t in terms]
    for t, c in zip(terms, coefs):
        params, _ = t.contract_parameters(c, 0.0, meas.mass_kg, meas.g_mps2)
        findings.append({"effect": t.effect, "parameters": params})
    # an unphysical fit (a force term of the wrong sign beside these) is no force law: its terms alone can be
    # many g (a stiff flight the integrator crawls through for minutes); its findings are shown, not simulated
    simulated = terms and not fl["unphysical"]
    f_fit = fit_flights(meas, tuple(terms), fixed_coefs=coefs) if simulated else base.flights
    kind = im["kind"]
    model = fit_model(meas, structure=s_fit, flights=f_fit)
    if kind != "none":
        c = im["coefs"]
        cor = type(model.cor)(kind=kind, coefs=np.asarray(c), cov=np.zeros((len(c), len(c))), sse=0.0, n=0, dof=1,
                              residual=np.zeros(0))
        model = FittedModel(structure=model.structure, flights=model.flights, impacts=model.impacts, cor=cor,
                            g_mps2=model.g_mps2)
        if kind in ("asymmetric_restitution", "plate_and_speed"):
            findings.append({"effect": "asymmetric_restitution", "parameters": {"cor_top": c[0], "cor_bottom": c[1]}})
        if kind in ("velocity_dependent_restitution", "plate_and_speed"):
            e0 = c[0] if kind == "velocity_dependent_restitution" else c[1]
            findings.append({"effect": "velocity_dependent_restitution",
                             "parameters": {"cor_at_zero": e0, "slope_s_per_m": c[-1]}})
    run = full_run(meas, model)
    return jsonable({"baseline_deviation": base_run.deviation, "findings": findings,
                     "final_deviation": run.deviation, "flight_terms_simulated": bool(simulated),
                     "raw": {"flights": fl, "impacts": im, "structure": st},
                     "replay_start_s": float(run.t_s[0]) if run.t_s.size else None})


def calibrate(controls: list[Measured]) -> dict:
    """Smallest thresholds (on a log grid) that give no finding on any of the control recordings."""
    grids = {"flight_mps2": np.geomspace(0.05, 30.0, 48), "cor": np.geomspace(0.002, 0.5, 40),
             "harmonic_m": np.geomspace(1e-8, 1e-4, 33)}
    out = {}
    for key, grid in grids.items():
        best = grid[0]
        for meas in controls:
            for lam in grid:
                if key == "flight_mps2":
                    r = sindy_flights(meas, lam)
                    clean = not r["terms"] and not r["unphysical"]
                elif key == "cor":
                    clean = sindy_impacts(meas, lam)["kind"] == "none"
                else:
                    clean = not sindy_structure(meas, lam)["orders"]
                if clean:
                    best = max(best, lam)
                    break
            else:
                best = grid[-1]
        out[key] = float(best)
    return out
