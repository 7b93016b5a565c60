"""Compare a results.json mapping with a synthetic recording's truth file (contract ``vibro.truth/1``).

Impacts are matched to the nearest true impact within ``tol_s``; errors are absolute. Structure errors
use the truth's amplitude and frequency. Friction: when the truth lists ``flights`` with ``friction_n``
(vibro_sim's synthetic rig does: the mean force over each flight), each fitted flight is compared with
the true flight holding its mid time; otherwise with the effects (``coulomb_friction``: -force_n on up
flights, +force_n on down flights, ignoring apex flips; no force effect: 0).
"""

from __future__ import annotations

import numpy as np

from vibro_model.constants import G_MPS2
from vibro_model.units import s_to_ms

FORCE_EFFECTS = ("coulomb_friction", "viscous_drag", "quadratic_drag")


def compare_to_truth(results: dict, truth: dict, mass_kg: float, g_mps2: float = G_MPS2, tol_s: float = 0.002
                     ) -> dict:
    """Accuracy figures of ``results`` against ``truth``: COR and impact-time errors, plate agreement,
    structure amplitude (%) and frequency (Hz) errors, friction errors in % of the ball's weight."""
    out = _impact_errors(results, truth, tol_s)
    s, st = results.get("structure", {}), truth.get("structure", {})
    if st.get("amplitude_mm"):
        out["amplitude_err_pct"] = 100 * abs(s["amplitude_mm"] - st["amplitude_mm"]) / st["amplitude_mm"]
    if st.get("frequency_hz"):
        out["frequency_err_hz"] = abs(s["frequency_hz"] - st["frequency_hz"])
    errs = _friction_errors(results, truth, mass_kg * g_mps2)
    if errs:
        out["friction_mean_pct_weight"] = 100 * float(np.mean(errs))
        out["friction_max_pct_weight"] = 100 * float(np.max(errs))
    return out


def _impact_errors(results: dict, truth: dict, tol_s: float) -> dict:
    """Counts, and the COR, impact-time (ms) and plate errors of the impacts matched within ``tol_s`` (s)."""
    t_true = np.array([i["t"] for i in truth.get("impacts", [])], float)
    cor_err, t_err, plate_ok = [], [], []
    for imp in results.get("impacts", []):
        if t_true.size == 0:
            break
        k = int(np.argmin(np.abs(t_true - imp["t"])))
        if abs(t_true[k] - imp["t"]) > tol_s:
            continue
        ti = truth["impacts"][k]
        cor_err.append(abs(imp["cor"] - ti["cor"]))
        t_err.append(abs(imp["t"] - ti["t"]))
        plate_ok.append(imp["plate"] == ti["plate"])
    out: dict = {"n_matched": len(cor_err), "n_results": len(results.get("impacts", [])), "n_truth": int(t_true.size)}
    if cor_err:
        out.update(cor_mae=float(np.mean(cor_err)), cor_max=float(np.max(cor_err)),
                   t_mae_ms=s_to_ms(float(np.mean(t_err))), t_max_ms=s_to_ms(float(np.max(t_err))),
                   plate_agreement=float(np.mean(plate_ok)))
    return out


def _friction_errors(results: dict, truth: dict, weight_n: float) -> list[float]:
    """Each fitted flight's friction error as a fraction of the ball's weight ``weight_n`` (N): against the true
    flight holding its mid time, else against the effects (none when a drag effect is in the truth)."""
    effects = {e.get("effect"): e.get("parameters", {}) for e in truth.get("effects", [])}
    tfl = [f for f in truth.get("flights", []) if f.get("friction_n") is not None]
    errs: list[float] = []
    if tfl:
        for f in results.get("flights", []):
            if f.get("friction_n") is None:
                continue
            mid = 0.5 * (f.get("t_first_frame", f["t_start"]) + f.get("t_last_frame", f["t_end"]))
            match = [g for g in tfl if g["t_start"] < mid < g["t_end"]]
            if match:
                errs.append(abs(f["friction_n"] - match[0]["friction_n"]) / weight_n)
    elif not any(name in effects for name in FORCE_EFFECTS[1:]):
        f0 = float(effects.get("coulomb_friction", {}).get("force_n", 0.0))
        for f in results.get("flights", []):
            if f.get("friction_n") is None:
                continue
            expect = -f0 if f["direction"] == "up" else f0
            errs.append(abs(f["friction_n"] - expect) / weight_n)
    return errs
