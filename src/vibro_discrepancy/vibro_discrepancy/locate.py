"""Where the model and the recording disagree: which flights/impacts, which phase, from when on, and
how large compared with the measurement noise floor (estimated from the data).

A flight disagrees when its one-step shape residual exceeds ``FLIGHT_FLAG`` x the per-frame noise floor
(the RMS of pure noise over ~20 frames stays within ~1.3x of it); an impact when its predicted velocity
after the impact misses the measured one by more than ``IMPACT_FLAG`` x its noise floor (the std of the
measured post-impact velocity from the next flight's fit, floored by the COR measurement noise times the
speed) or its predicted time misses by more than ``IMPACT_FLAG`` x (2 sigma / relative speed).

A real contact gives every impact its own COR, so the velocity after an impact misses any constant law
by the physical COR scatter (~100x the measurement noise with sigma 0.015). That is not a model error:
the velocity errors count as disagreements only when the model's COR errors show a systematic pattern
(a plate difference, a slope with impact speed, a trend or step in time:
:func:`.systematic.cor_patterns`); otherwise the impacts are reported as scattering randomly.
"""

from __future__ import annotations

import numpy as np

from vibro_discrepancy.data import Measured
from vibro_discrepancy.library import FlightTerm
from vibro_discrepancy.model import FittedModel
from vibro_discrepancy.onestep import OneStep
from vibro_discrepancy.systematic import cor_patterns

FLIGHT_FLAG = 2.0
IMPACT_FLAG = 4.0
ONSET_SHARE = 0.75


def _onset(t: np.ndarray, flagged: np.ndarray) -> float | None:
    """Earliest time from which at least ONSET_SHARE of the items are flagged (None: never)."""
    order = np.argsort(t)
    t, f = t[order], flagged[order].astype(float)
    n = f.size
    for i in range(n):
        if f[i] and f[i:].mean() >= ONSET_SHARE:
            return float(t[i])
    return None


def _count(mask: np.ndarray, sel: np.ndarray) -> str:
    return f"{int(np.sum(mask & sel))}/{int(np.sum(sel))}"


def flight_ratios(os: OneStep) -> np.ndarray:
    return os.flight_rms_m / max(os.flight_sigma_m, 1e-15)


def impact_ratios(os: OneStep, cor_noise: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(velocity-after error, time error) in units of their noise floors (NaN: not predicted)."""
    sig_v = np.sqrt(np.nan_to_num(os.dv_sigma_mps, nan=0.0) ** 2 * 2 + (cor_noise * os.impact_speed_mps) ** 2)
    sig_v = np.maximum(sig_v, 1e-7)
    sig_t = 2.0 * os.flight_sigma_m / np.maximum(os.impact_speed_mps, 1e-3)
    return np.abs(os.impact_dv_mps) / sig_v, np.abs(os.impact_dt_s) / sig_t


def _when(onset: float | None, t_s: np.ndarray) -> str:
    """Words for when the disagreement starts: ``onset`` (s) against the first time ``t_s`` (s) judged."""
    if onset is not None and onset <= float(np.min(t_s)):
        return "throughout"
    return f"from t = {onset:.3f} s on" if onset is not None else "scattered over the recording"


def _earlier(first: float | None, onset: float | None) -> float | None:
    """The first disagreement (s) so far, ``first``, updated with a later stage's ``onset`` (None: none known)."""
    return onset if first is None or (onset is not None and onset < first) else first


def _flight_location(os: OneStep) -> tuple[dict, str, float | None]:
    """The flights' disagreement: (data, words, onset in s when any flight disagrees, else None)."""
    r = flight_ratios(os)
    ok = np.isfinite(r)
    flag = ok & (r > FLIGHT_FLAG)
    up = os.flight_direction == "up"
    onset = _onset(os.flight_t_s[ok], flag[ok]) if ok.any() else None
    d = {"n": int(ok.sum()), "n_disagree": int(flag.sum()),
         "ascending": _count(flag, up & ok), "descending": _count(flag, ~up & ok),
         "median_x_noise": float(np.median(r[ok])) if ok.any() else None,
         "max_x_noise": float(np.max(r[ok])) if ok.any() else None,
         "from_s": onset, "disagreeing_flights": [int(i) for i in np.flatnonzero(flag)]}
    if not flag.any():
        return d, f"flights: all {d['n']} within {FLIGHT_FLAG:g}x the noise floor", None
    when = _when(onset, os.flight_t_s[ok])
    return d, (f"flights: {d['n_disagree']}/{d['n']} disagree (towards the top plate {d['ascending']}, towards "
               f"the bottom plate {d['descending']}), shape residual median {d['median_x_noise']:.1f}x, max "
               f"{d['max_x_noise']:.1f}x the noise floor ({os.flight_sigma_m * 1e6:.2f} um per frame), {when}"), onset


def _impact_data(os: OneStep, ok: np.ndarray, flag: np.ndarray, ratios: tuple[np.ndarray, np.ndarray],
                 patterns: list, random_scatter: bool) -> dict:
    """The impacts' disagreement as data: counts per plate and speed half, the median errors in noise floors.
    ``ok``: the impacts judged; ``flag``: those that disagree; ``ratios``: the (velocity, time) errors in noise
    floors; ``patterns``: the COR errors' patterns; ``random_scatter``: velocity errors set aside as scatter."""
    rv, rt = ratios
    top = os.impact_plate == "top"
    spd = os.impact_speed_mps
    fast = spd >= np.median(spd[ok]) if ok.any() else np.zeros_like(top)
    return {"n": int(ok.sum()), "n_disagree": int(flag.sum()), "top": _count(flag, top & ok),
            "bottom": _count(flag, ~top & ok), "fast": _count(flag, fast & ok), "slow": _count(flag, ~fast & ok),
            "velocity_median_x_noise": float(np.nanmedian(rv)) if np.isfinite(rv).any() else None,
            "time_median_x_noise": float(np.nanmedian(rt)) if np.isfinite(rt).any() else None,
            "cor_error_rms": float(np.sqrt(np.nanmean(os.impact_de ** 2))) if np.isfinite(os.impact_de).any()
            else None,
            "from_s": _onset(os.impact_t_s[ok], flag[ok]) if ok.any() else None,
            "disagreeing_impacts": [int(i) for i in np.flatnonzero(flag)],
            "velocity_random_scatter": random_scatter,
            "cor_patterns": [m.what() for m in patterns]}


def _impact_location(os: OneStep, cor_noise: float) -> tuple[dict, str, float | None]:
    """The impacts' disagreement: (data, words, onset in s when any impact disagrees, else None). The velocity
    errors count only when the COR errors show a pattern (module docstring)."""
    rv, rt = impact_ratios(os, cor_noise)
    ok = np.isfinite(rv) | np.isfinite(rt)
    flag_v = np.isfinite(rv) & (rv > IMPACT_FLAG)
    patterns = cor_patterns(os.impact_t_s, os.impact_plate, os.impact_speed_mps, os.impact_de, 0.0,
                            n_tests=1, shapes=("plate", "speed"))
    de = os.impact_de[np.isfinite(os.impact_de)]
    random_scatter = bool(flag_v.any()) and not patterns
    if random_scatter:
        flag_v[:] = False   # the COR scatters per impact: a property of the contact, not a model error
    flag_t = np.isfinite(rt) & (rt > IMPACT_FLAG)
    flag = flag_v | flag_t
    d = _impact_data(os, ok, flag, (rv, rt), patterns, random_scatter)
    onset = d["from_s"]
    scatter_words = (f"the velocity after scatters with the per-impact COR (RMS COR error "
                     f"{float(np.sqrt(np.mean(de ** 2))):.4f}, {d['velocity_median_x_noise']:.0f}x the "
                     f"measurement noise) with no pattern in plate, speed or time: random contact scatter, not "
                     f"a model error") if random_scatter else ""
    scatter = f"; {scatter_words}" if scatter_words else ""
    if not flag.any():
        return d, f"impacts: all {d['n']} within {IMPACT_FLAG:g}x their noise floor" + scatter, None
    what = []
    if flag_v.any():
        what.append(f"velocity after median {d['velocity_median_x_noise']:.1f}x noise")
    if flag_t.any():
        what.append(f"impact time median {d['time_median_x_noise']:.1f}x noise")
    if patterns:
        what.append("systematic in the COR: " + "; ".join(d["cor_patterns"]))
    return d, (f"impacts: {d['n_disagree']}/{d['n']} disagree (top {d['top']}, bottom {d['bottom']}; fast "
               f"{d['fast']}, slow {d['slow']}), {', '.join(what)}, {_when(onset, os.impact_t_s[ok])}"
               + scatter), onset


def locate(os: OneStep, cor_noise: float = 0.0, stages=("flights", "impacts")) -> dict:
    """Data and plain words about where ``os`` (one model's one-step errors) disagrees with the data:
    ``flights``/``impacts`` (the ``stages`` asked for that have any), ``from_s`` the first disagreement (s),
    ``words`` a sentence per stage and ``text`` them joined."""
    out: dict = {"words": []}
    t_first = None
    if "flights" in stages and os.flight_rms_m.size:
        out["flights"], words, t_first = _flight_location(os)
        out["words"].append(words)
    if "impacts" in stages and os.impact_t_s.size:
        out["impacts"], words, onset = _impact_location(os, cor_noise)
        out["words"].append(words)
        t_first = _earlier(t_first, onset)
    out["from_s"] = t_first
    out["text"] = "; ".join(out["words"])
    return out


def structure_words(residual_m: np.ndarray, t_s: np.ndarray, sigma_m: float, frequency_hz: float) -> str:
    """Plain words on a structure residual (the pure sine's misfit)."""
    r = np.asarray(residual_m, dtype=float)
    peak = float(np.max(np.abs(r))) if r.size else 0.0
    # phase of the cycle where the misfit is largest
    ph = (np.asarray(t_s) * frequency_hz) % 1.0
    k = int(np.argmax(np.abs(r))) if r.size else 0
    return (f"structure: the pure sine misses the structure track by up to {peak * 1e6:.1f} um "
            f"({peak / max(sigma_m, 1e-15):.0f}x the noise floor {sigma_m * 1e6:.2f} um), periodically every cycle "
            f"(largest at cycle phase {ph[k]:.2f}), throughout")


def flight_term_where(meas: Measured, steps: OneStep, model_after: FittedModel, term: FlightTerm,
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
    parts = [f"{np.mean(v):+.3f} m/s^2 on flights towards the {'top' if d == 'up' else 'bottom'} plate"
             for d, v in sorted(extra.items(), reverse=True)]
    return f"{words}; {term.effect} adds a mean acceleration of " + " and ".join(parts)


def cor_law_where(meas: Measured, steps: OneStep, model_after: FittedModel, cor_noise: float) -> str:
    """Where a COR law shows: the before-model's impact mismatch and the measured COR per plate."""
    words = locate(steps, cor_noise, stages=("impacts",))["text"]
    imp = model_after.impacts
    parts = []
    for p in ("top", "bottom"):
        sel = imp.plate == p
        if sel.any():
            parts.append(f"{p}: COR {np.mean(imp.cor[sel]):.3f} +- {np.std(imp.cor[sel]):.3f} at "
                         f"{np.mean(imp.speed[sel]):.3f} m/s")
    return f"{words}; measured " + ", ".join(parts)
