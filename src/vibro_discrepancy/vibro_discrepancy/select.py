"""Choose the terms the data need, stage by stage, with a significance threshold and a noise floor.

Order: structure (harmonics, from the structure track alone), then flights (force terms and tilt,
from the ball track with the flight states free), then impacts (COR law, on CORs recomputed with the
chosen structure and flight models: a missing force or harmonic biases the identified velocities).

A term is accepted when (1) it is significant: the drop of the sum of squares, in units of the noise
floor sigma^2 estimated from the data (differences of consecutive frames, free of the model), exceeds
the chi^2 quantile at ``ALPHA`` (F-test against the residual scatter for CORs), and (2) it matters: the
RMS of what it explains exceeds a fraction of the noise floor (flights: ``MIN_EXPLAINED_SIGMA`` sigma,
structure: ``MIN_HARMONIC_SIGMA`` sigma of amplitude) or, for CORs, ``MIN_COR_RMS``. (2) keeps the small
systematic errors of DIC (sub-pixel bias, ~0.1 sigma) from becoming findings. (3) It is physically more
than negligible (:mod:`.library`'s floors, docs/method.md "Physical floors"): a flight term's force at the
fastest measured speed is at least ``FORCE_FLOOR_OF_WEIGHT`` (1e-3) of the ball's weight, a harmonic's COR
change at least ``COR_EFFECT_FLOOR`` (1e-3); a COR law's ``MIN_COR_RMS`` is above that floor already. (3)
keeps a long recording, whose chi^2 grows with its length, from claiming what does not matter. Singles first; a pair is
tried when the best single leaves a significant, visible mismatch. Look-alikes are separated by their
signatures: Coulomb (sign flips with the direction, speed-independent) vs tilt (one sign) vs viscous
(linear in speed) vs quadratic (speed squared) are different columns of the same regression, so the
best fit wins by chi^2; asymmetric vs velocity-dependent restitution by the within-plate speed
dependence (see :func:`select_cor`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace

import numpy as np

from vibro_discrepancy.data import Measured, speed_mps
from vibro_discrepancy.fitting import (
    FlightModelFit,
    ImpactSet,
    StructureModelFit,
    fit_cor,
    fit_flights,
    fit_structure_harmonics,
)
from vibro_discrepancy.library import (
    COR_EFFECT_FLOOR,
    FLIGHT_TERMS,
    FORCE_FLOOR_OF_WEIGHT,
    CandidateLibrary,
    FlightTerm,
    StructureHarmonics,
)
from vibro_discrepancy.model import COR_TERMS
from vibro_model.codec import json_number as _f
from vibro_model.constants import G_MPS2
from vibro_model.tail_probability import chi2_sf, f_sf
from vibro_sim.deviation import cor_variance_share

ALPHA = 1e-6                 # flights / structure: chi^2 tail probability for a term to count
ALPHA_COR = 1e-3             # CORs: F-test (few impacts, scatter estimated from the data)
MIN_EXPLAINED_SIGMA = 0.5    # flight term: explained RMS per frame >= this x noise floor
MIN_HARMONIC_SIGMA = 3.0     # harmonic amplitude >= this x structure noise floor
MIN_COR_RMS = 0.004          # COR law: RMS change of the predicted COR over the impacts
# (also the COR law's physical floor: an RMS change of 0.004 is a change of >= 0.008 over the measured
# impacts, 8x COR_EFFECT_FLOOR, so a law whose effect over the measured speeds is < 1e-3 is never accepted)
UNEXPLAINED_RATIO = 1.5      # residual RMS / noise floor above which a stage's mismatch is unexplained


@dataclass(kw_only=True)
class Decision:
    """One tested candidate: its chi^2 (or F) statistic, p-value, explained size and verdict."""

    label: str
    statistic: float
    p_value: float
    explained: float
    accepted: bool
    note: str = ""
    variance_share: float | None = None   # COR laws: share of the COR variance beyond noise explained

    def to_dict(self) -> dict:
        out = {"candidate": self.label, "statistic": _f(self.statistic), "p_value": _f(self.p_value),
               "explained": _f(self.explained), "accepted": self.accepted, "note": self.note}
        if self.variance_share is not None:
            out["variance_share"] = _f(self.variance_share)
        return out


@dataclass(kw_only=True)
class StageResult:
    name: str
    chosen: tuple
    decisions: list[Decision] = field(default_factory=list)
    residual_ratio: float = float("nan")   # residual RMS / noise floor of the chosen model
    unexplained: bool = False
    notes: list[str] = field(default_factory=list)
    alternatives: list[str] = field(default_factory=list)


# --- structure ---------------------------------------------------------------------------------------

def select_structure(meas: Measured, sigma_m: float) -> tuple[StructureModelFit, StageResult]:
    """Harmonics 2 and 3 of the structure motion: each kept when significant and >= MIN_HARMONIC_SIGMA
    noise floors in amplitude. The noise floor ``sigma_m`` comes from 5th differences of the track."""
    t, y, f0 = meas.t_s, meas.structure_m, meas.frequency_hz
    envelope = meas.drive_envelope
    if envelope is not None:   # a drive that moved: its change is not a harmonic (a drift once gave h2 "found")
        t, y = envelope.demodulated(t, y, float(meas.structure.offset_m or 0.0), f0)
    fits = {o: fit_structure_harmonics(t, y, f0, o) for o in ((1,), (1, 2), (1, 3), (1, 2, 3))}
    sig2 = max(sigma_m, 1e-12) ** 2
    stage = StageResult(name="structure", chosen=())
    full = fits[(1, 2, 3)]
    cor_change = _harmonic_cor_change(meas, full)
    chosen, negligible = [], []
    for k in (2, 3):
        without = fits[(1, 5 - k)]   # the other harmonic kept: test k given it
        chi = (without.sse - full.sse) / sig2
        p = chi2_sf(chi, 2)
        amp = full.harmonic_amplitudes()[k]
        change = cor_change(k, amp)
        ok = p < ALPHA and amp >= MIN_HARMONIC_SIGMA * sigma_m and not change < COR_EFFECT_FLOOR
        note = f"amplitude {amp * 1e6:.3g} um = {amp / sigma_m:.1f} x noise floor"
        if p < ALPHA and change < COR_EFFECT_FLOOR:
            note += f"; negligible: COR change {change:.2g} < floor {COR_EFFECT_FLOOR:g}"
        stage.decisions.append(Decision(label=f"harmonic {k}", statistic=chi, p_value=p, explained=amp / sigma_m,
                                        accepted=ok, note=note))
        if ok:
            chosen.append(k)
        elif p < ALPHA and amp >= MIN_HARMONIC_SIGMA * sigma_m:
            negligible.append(k)
    best = fits[(1,) + tuple(chosen)]
    stage.chosen = tuple(chosen)
    # a harmonic below its floor explains the track's residual all the same: not a mismatch left unexplained
    explained = fits[(1,) + tuple(sorted(chosen + negligible))]
    if negligible:
        stage.notes.append(f"harmonic(s) {', '.join(map(str, negligible))} significant but negligible (COR change "
                           f"< {COR_EFFECT_FLOOR:g}): not a finding; the residual is judged with them")
    stage.residual_ratio = explained.sigma / sigma_m if sigma_m > 0 else float("nan")
    stage.unexplained = stage.residual_ratio > UNEXPLAINED_RATIO
    return best, stage


def _harmonic_cor_change(meas: Measured, fit: StructureModelFit):
    """(order, amplitude m) -> the COR change the harmonic makes (:meth:`.StructureHarmonics.cor_effect`) at the
    recording's median impact (relative speed, COR) under ``fit``'s fundamental; NaN (no floor) without
    impacts."""
    a1 = fit.motion().amplitude_m
    drive = 2.0 * math.pi * meas.frequency_hz * a1
    speeds = [speed_mps(i) for i in meas.impacts if i.cor is not None]
    cors = [float(i.cor) for i in meas.impacts if i.cor is not None]
    if not speeds or a1 <= 0:
        return lambda order, amp: math.nan
    v, e = float(np.median(speeds)), float(np.median(cors))
    return lambda order, amp: StructureHarmonics.cor_effect(order, amp / a1, drive, e, v)


# --- flights -----------------------------------------------------------------------------------------

def _explained_rms(sse_before: float, sse_after: float, n: int) -> float:
    return math.sqrt(max(sse_before - sse_after, 0.0) / max(n, 1))


def _fastest_speed(meas: Measured) -> float:
    """The fastest ball speed (m/s) of the identified flights' parabolas over their samples."""
    return max((float(np.max(np.abs(f.v_nominal(f.t_s)))) for f in meas.flights if f.t_s.size), default=0.0)


def _negligible(fit: FlightModelFit, meas: Measured, speed: float) -> list[str]:
    """The terms of ``fit`` whose force at ``speed`` is below the physical floor (:data:`FORCE_FLOOR_OF_WEIGHT`
    m g), each as "effect F = x m g"; empty when every term matters."""
    weight = meas.mass_kg * G_MPS2   # the ball's weight, whatever the axis' orientation
    return [f"{t.effect} {t.peak_force_n(float(c), speed, meas.mass_kg) / weight:.2g} m g" for t, c in
            zip(fit.terms, fit.coefs) if t.negligible(float(c), speed, meas.mass_kg, G_MPS2)]


def _active(fit: FlightModelFit, axis_tilt_deg: float = 0.0) -> bool:
    """Every term of ``fit`` is in play: off its lower bound (:meth:`FlightTerm.lower_bound`: 0 for a force, which
    NNLS leaves at 0 when the data do not want it; a tilt on a tilted axis may be negative, never 0)."""
    for t, c in zip(fit.terms, fit.coefs):
        lb = t.lower_bound(fit.g_mps2, axis_tilt_deg)
        if not (c > lb and (c > 0.0 if lb == 0.0 else c != 0.0)):
            return False
    return True


def _summary(fit: FlightModelFit) -> FlightModelFit:
    """``fit`` without its per-flight arrays (residuals, integration grids: ~1 kB per frame of the
    recording), for a candidate that is only compared (sse, coefficients), never used as the model."""
    return replace(fit, residuals=[], grids=[])


def select_flights(meas: Measured, sigma_m: float, terms: tuple[FlightTerm, ...] = FLIGHT_TERMS
                   ) -> tuple[FlightModelFit, StageResult]:
    """Flight terms: the best single by chi^2; then the best pair if it beats that single significantly
    and visibly. ``sigma_m``: per-frame noise floor of the ball track (3rd differences)."""
    stage = StageResult(name="flights", chosen=())
    base = fit_flights(meas)
    n = base.n_points
    sig2 = max(sigma_m, 1e-12) ** 2
    if len(meas.flights) < 3:
        stage.notes.append("fewer than 3 free flights: flight terms not tested")
        stage.residual_ratio = math.sqrt(base.sse / max(n, 1)) / sigma_m
        return base, stage
    singles: dict[tuple[str, ...], FlightModelFit] = {}
    lead = None    # the best single so far: the only one kept whole
    for t in terms:
        key, f = (t.effect,), fit_flights(meas, (t,))
        if lead is None or f.sse < singles[lead].sse:
            if lead is not None:
                singles[lead] = _summary(singles[lead])
            lead = key
        else:
            f = _summary(f)
        singles[key] = f
    speed = _fastest_speed(meas)
    for key, f in singles.items():
        chi = (base.sse - f.sse) / sig2
        p = chi2_sf(chi, 1)
        ex = _explained_rms(base.sse, f.sse, n) / sigma_m
        small = _negligible(f, meas, speed) if p < ALPHA else []
        ok = p < ALPHA and ex >= MIN_EXPLAINED_SIGMA and _active(f, meas.axis_tilt_deg) and not small
        stage.decisions.append(Decision(label=key[0], statistic=chi, p_value=p, explained=ex, accepted=ok,
                                        note=f"explains {ex:.2f} x noise floor per frame" + _floor_note(small)))
    ranked = sorted(singles.items(), key=lambda kv: kv[1].sse)
    best_key, best = ranked[0]
    best_dec = next(d for d in stage.decisions if d.label == best_key[0])
    chosen, current = (), base
    explained = base    # the residual is judged after a term below its floor too: not a mismatch left unexplained
    if not best_dec.accepted and _floor_only(best_dec, best, meas.axis_tilt_deg):
        explained = best
        stage.notes.append(f"{best_key[0]} significant but negligible (below its physical floor): not a finding; "
                           "the residual is judged with it")
    if best_dec.accepted:
        chosen, current = best_key, best
        # runner-up look-alike: note how much worse it fits
        if len(ranked) > 1:
            rk, rf = ranked[1]
            ratio = math.sqrt(rf.sse / max(best.sse, 1e-300))
            stage.notes.append(f"{best_key[0]} fits {ratio:.2f}x better (RMS) than the next candidate {rk[0]}")
    # pairs when one is not enough (only the best is kept whole)
    pk, pf = None, None
    for a, b in itertools.combinations(terms, 2):
        f = fit_flights(meas, (a, b))
        if pf is None or f.sse < pf.sse:
            pk, pf = (a.effect, b.effect), f
    if pf is not None:
        ref = current
        dp = 2 - len(chosen)
        chi = (ref.sse - pf.sse) / sig2
        p = chi2_sf(chi, max(dp, 1))
        ex = _explained_rms(ref.sse, pf.sse, n) / sigma_m
        small = _negligible(pf, meas, speed) if p < ALPHA else []
        ok = p < ALPHA and ex >= MIN_EXPLAINED_SIGMA and _active(pf, meas.axis_tilt_deg) and not small
        stage.decisions.append(Decision(label=" + ".join(pk), statistic=chi, p_value=p, explained=ex, accepted=ok,
                                        note=f"against {' + '.join(chosen) or 'baseline'}: explains {ex:.2f} x noise"
                                        + _floor_note(small)))
        if ok:
            chosen, current = pk, pf
    stage.chosen = chosen
    resid = current if chosen else explained
    stage.residual_ratio = math.sqrt(resid.sse / max(n, 1)) / sigma_m
    stage.unexplained = stage.residual_ratio > UNEXPLAINED_RATIO
    return current, stage


def _floor_only(decision: Decision, fit: FlightModelFit, axis_tilt_deg: float = 0.0) -> bool:
    """True when ``decision`` was refused by the physical floor alone (significant, visible, positive)."""
    return (decision.p_value < ALPHA and decision.explained >= MIN_EXPLAINED_SIGMA and _active(fit, axis_tilt_deg)
            and "negligible" in decision.note)


def _floor_note(negligible: list[str]) -> str:
    """The decision note's clause for terms below the force floor (empty when none is)."""
    if not negligible:
        return ""
    return (f"; negligible: force at the fastest flight speed {', '.join(negligible)} < floor "
            f"{FORCE_FLOOR_OF_WEIGHT:g} m g")


# --- impacts -----------------------------------------------------------------------------------------

def _f_test(small, big) -> tuple[float, float]:
    """F statistic and p-value of nested linear models (big has more parameters)."""
    dp = big.p - small.p
    if dp <= 0 or big.n <= big.p or big.sse <= 0:
        return float("nan"), 1.0
    F = ((small.sse - big.sse) / dp) / (big.sse / big.dof)
    return F, f_sf(F, dp, big.dof)


def select_cor(impacts: ImpactSet, cor_noise: float) -> tuple[str, dict, StageResult]:
    """COR law: constant (baseline), per plate (asymmetric) or linear in impact speed. Both are tested
    against the constant law (F-test, ``ALPHA_COR``) and must change the predicted COR by an RMS of at
    least ``MIN_COR_RMS`` (or 3x the COR measurement noise ``cor_noise``).

    When both explain the data (speeds cluster by plate, so the two laws coincide), the pooled
    within-plate slope decides: consistent with the speed law's slope and not with 0 -> velocity
    dependent; consistent with 0 and not with that slope -> asymmetric. If it cannot tell (within-plate
    speeds barely vary), the sign decides: a COR that falls with speed (slope > 0) is the physical
    behaviour of a speed-dependent contact; a faster plate restituting more is not, so -> asymmetric.
    The indistinguishable alternative is listed in ``stage.alternatives``.
    """
    stage = StageResult(name="impacts", chosen=())
    fits = {k: fit_cor(impacts, term, k) for k, term in COR_TERMS.items()}
    n = impacts.cor.size
    if n < 4:
        stage.notes.append(f"only {n} impacts: COR law not tested")
        return "none", fits, stage
    base = fits["none"]
    floor = max(MIN_COR_RMS, 3.0 * cor_noise)
    ok = {}
    for kind in ("asymmetric_restitution", "velocity_dependent_restitution"):
        f = fits[kind]
        F, p = _f_test(base, f)
        pred = impacts.cor - f.residual
        ex = float(np.sqrt(np.mean((pred - np.mean(pred)) ** 2)))
        good = p < ALPHA_COR and ex >= floor and (np.all(np.isfinite(f.coefs)))
        if kind == "asymmetric_restitution" and (np.sum(impacts.plate == "top") < 2 or
                                                 np.sum(impacts.plate == "bottom") < 2):
            good = False
        ok[kind] = good
        share = law_variance_share(impacts, f)
        stage.decisions.append(Decision(label=kind, statistic=F, p_value=p, explained=ex, accepted=good,
                                        note=f"COR RMS change {ex:.4f} (floor {floor:.4f})", variance_share=share))
    if ok["asymmetric_restitution"] and ok["velocity_dependent_restitution"]:
        kind, why, alt = _separate(impacts, fits)
        stage.notes.append(why)
        if alt:
            stage.alternatives.append(alt)
    elif ok["asymmetric_restitution"]:
        kind = "asymmetric_restitution"
    elif ok["velocity_dependent_restitution"]:
        kind = "velocity_dependent_restitution"
    else:
        kind = "none"
    stage.chosen = (kind,) if kind != "none" else ()
    return kind, fits, stage


def law_variance_share(impacts: ImpactSet, fit) -> float | None:
    """Share of the per-impact COR variance the fitted law ``fit`` explains beyond the COR measurement
    noise (mean cor_std^2 of the impacts): :func:`vibro_sim.deviation.cor_variance_share`."""
    if impacts.cor.size == 0:
        return None
    stds = np.asarray(impacts.cor_std, dtype=float)
    noise_var = float(np.mean(stds[np.isfinite(stds)] ** 2)) if np.isfinite(stds).any() else 0.0
    return cor_variance_share(impacts.cor, impacts.cor - fit.residual, noise_var, fit.p)


def _separate(impacts: ImpactSet, fits: dict) -> tuple[str, str, str]:
    """Asymmetric vs velocity-dependent restitution when both explain the CORs."""
    both = fits["plate_and_speed"]
    sv = float(fits["velocity_dependent_restitution"].coefs[1])
    sw = float(both.coefs[2])
    se = float(math.sqrt(both.cov[2, 2])) if np.isfinite(both.cov[2, 2]) else float("inf")
    z0 = abs(sw) / se if se > 0 else float("inf")
    zv = abs(sw - sv) / se if se > 0 else float("inf")
    informative = se < abs(sv) / 3.0
    txt = (f"within-plate slope {sw:.3f} +- {se:.3f} s/m vs the speed law's {sv:.3f} s/m")
    if informative and zv < 3 and z0 >= 3:
        return "velocity_dependent_restitution", txt + ": the COR follows the speed within each plate", ""
    if informative and z0 < 3 and zv >= 3:
        return "asymmetric_restitution", txt + ": within each plate the COR ignores the speed", ""
    sa, sd = fits["asymmetric_restitution"].sse, fits["velocity_dependent_restitution"].sse
    if informative and max(sa, sd) > 2.0 * min(sa, sd):
        kind = "asymmetric_restitution" if sa < sd else "velocity_dependent_restitution"
        return kind, txt + f": {kind} fits clearly better", ""
    if sv > 0:
        return ("velocity_dependent_restitution",
                txt + ": impact speeds cluster by plate, so a plate difference and a speed law coincide; the COR "
                "falls with speed (physical sign of a speed-dependent contact)", "asymmetric_restitution")
    return ("asymmetric_restitution",
            txt + ": impact speeds cluster by plate; the faster plate restitutes more, which a speed-dependent "
            "contact does not do", "velocity_dependent_restitution")


# --- the selector as one object ---------------------------------------------------------------------

@dataclass(frozen=True)
class StagewiseSelector:
    """Selection stage by stage over a :class:`~.library.CandidateLibrary` (PySINDy's optimizer): the
    structure (:func:`select_structure`), the flights (:func:`select_flights`), the COR law
    (:func:`select_cor`). A stage whose library part is empty keeps the baseline and reports no stage."""

    def structure(self, meas: Measured, sigma_m: float, library: CandidateLibrary
                  ) -> tuple[StructureModelFit, StageResult | None]:
        if library.harmonics:
            return select_structure(meas, sigma_m)
        return fit_structure_harmonics(meas.t_s, meas.structure_m, meas.frequency_hz, (1,)), None

    def flights(self, meas: Measured, sigma_m: float, library: CandidateLibrary
                ) -> tuple[FlightModelFit, StageResult | None]:
        if library.flight_terms:
            return select_flights(meas, sigma_m, tuple(library.flight_terms))
        return fit_flights(meas), None

    def cor(self, impacts: ImpactSet, cor_noise: float, library: CandidateLibrary) -> tuple[str, StageResult]:
        """The chosen COR law's name ("none": the constant baseline) and the stage."""
        kind, _, stage = select_cor(impacts, cor_noise)
        if kind not in library.cor_terms:
            kind = "none"
            stage.chosen = ()
        return kind, stage
