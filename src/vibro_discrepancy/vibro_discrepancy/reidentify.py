"""Re-identification of the impacts with the discrepancy analysis' final model.

The paper's identification (Eq. 15, 16) measures every impact with a pure-sine structure and free
parabolas. Once the discrepancy engine has found that the structure holds harmonics or that a force
acts during the flights, those estimates are biased (about 0.03 in the COR with 5 % of 2nd harmonic,
up to 0.01 with aerodynamic drag). Here each impact is measured again under the engine's final model:

- time t_i where the final model's flights before and after the impact meet
  (:func:`vibro_discrepancy.fitting.impact_time`, Eq. 15 under the model),
- structure velocity from the structure fit at t_i (harmonics, and a modelled tone),
- ball velocities before/after from the flights integrated with the identified force law,
- COR e = -(v_after - v_s) / (v_before - v_s) (Eq. 16 with its sign),

all from :func:`vibro_discrepancy.fitting.recompute_impacts` (the engine's own computation, kept in
its ``final`` model), with a 1-sigma std propagated to first order (:func:`impact_stds`).

Only findings that change how an impact is *measured* trigger it: ``structure_harmonics``, the
flight terms (``coulomb_friction``, ``viscous_drag``, ``quadratic_drag``, ``gravity_tilt``) and an
``unexplained`` finding whose located structure tone was modelled (:mod:`.tone`; its parameters carry
the tone, its ``cor_method`` part is ``structure_tone``). A COR law (``asymmetric_restitution``,
``velocity_dependent_restitution``) describes the measured CORs and does not change them; any other
``unexplained`` mismatch has no model. A flight term that lowers the deviation without fitting the
residual's shape (``fits_residual_shape`` false: :mod:`.shape`, e.g. Coulomb friction absorbing part of a
force that depends on the ball's position) does not measure the impacts either: it would bias every COR
(measured: 0.003 mean error against 0.0014 for Eq. 16 on a position force of 20 % of the weight).
Without such a finding, or for an impact the final
model does not see from both sides (a flight too short to fit), the identification's values stay and
the impact's ``cor_method`` is ``"paper"``.

Plain module (no rclpy, no vibro_fit), the one place the impacts are measured again: :func:`reidentification`
is the stage the results assembler (:mod:`vibro_model.assemble`, which applies it) takes from ``vibro analyze``
and from the graph's ``discrepancy`` node, which publishes the re-measured impacts
(``vibro/impacts_final_model``); ``vibro results <bag>`` puts them back with :func:`reidentified_from_impacts`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Iterable, Sequence

import numpy as np

from vibro_discrepancy.data import Measured
from vibro_discrepancy.fitting import StructureModelFit
from vibro_discrepancy.library import FLIGHT_TERMS
from vibro_discrepancy.model import FittedModel
from vibro_discrepancy.tone import TONE_EFFECT, modelled_tone
from vibro_model.assemble import FrictionCorrection, LocalStructure, Reidentification
from vibro_model.constants import G_MPS2
from vibro_model.model_error import (
    LOCAL_HALF_WINDOW_PERIODS,
    ImpactSlopes,
    ModelError,
    flight_residual_slope,
    local_sine_slope,
)
from vibro_model.results import Impact, ResultsDocument

#: a re-measured COR keeps the final model's structure velocity only where that velocity, carried into the COR,
#: is off the local structure's by less than this (and 3 sigma): a quarter of the 0.002 a lab asks of every
#: impact's COR, and above the COR shift DIC noise gives a local structure fit (~1e-5)
COR_SUPPORT_FLOOR = 5e-4
#: findings whose model changes how an impact is measured (structure velocity, flight law); an
#: ``unexplained`` finding with a modelled structure tone counts as TONE_EFFECT (:mod:`.tone`)
MEASUREMENT_EFFECTS: tuple[str, ...] = ("structure_harmonics",) + tuple(t.effect for t in FLIGHT_TERMS) + (TONE_EFFECT,)


def measurement_effects(findings: Iterable[object]) -> list[str]:
    """The findings (contract mappings with ``effect``, or objects with ``.effect``) that change the
    measurement of an impact, in the order found."""
    out = []
    for f in findings:
        name = f.get("effect") if isinstance(f, dict) else getattr(f, "effect", None)
        details = f if isinstance(f, dict) else (getattr(f, "details", None) or {})
        if details.get("fits_residual_shape") is False:   # lowers D but leaves a shaped residual: not a
            continue                                      # model to measure the impacts with
        if modelled_tone(f):
            name = TONE_EFFECT
        if name in MEASUREMENT_EFFECTS and name not in out:
            out.append(name)
    return out


def _structure_velocity_gradient(fit: StructureModelFit, t_s: float) -> np.ndarray:
    """D v_s(t) / d parameters of the structure fit (:meth:`StructureModelFit.parameters`; central
    differences), m/s per unit."""
    p = fit.parameters()
    grad = np.zeros(p.size)
    for j in range(p.size):
        h = (1e-7 if j >= p.size - fit.n_frequencies else 1e-6) * max(abs(p[j]), 1e-9)
        pp, pm = p.copy(), p.copy()
        pp[j] += h
        pm[j] -= h
        grad[j] = (fit.velocity_with(pp, t_s) - fit.velocity_with(pm, t_s)) / (2 * h)
    return grad


def _flight_state_cov(meas: Measured, model: FittedModel, k: int) -> np.ndarray:
    """Covariance of flight k's own state (y0 m, v0 m/s at its reference time): sigma^2 (L^T L)^-1,
    L = [1, tau] over its fitted frames, sigma^2 the flights' pooled residual variance, with the shared force
    coefficients held (their part, independent of this one: the coefficients see only the residual off every
    flight's straight line, :func:`_coef_terms`)."""
    tau = meas.flights[k].tau_s
    L = np.column_stack([np.ones_like(tau), tau])
    s2 = model.flights.sse / max(model.flights.dof, 1)
    return s2 * np.linalg.inv(L.T @ L)


def _coef_terms(meas: Measured, model: FittedModel, kb: int, ka: int, tau_b: float,
                tau_a: float) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """(covariance of the flight force coefficients, (dy, dv)/dtheta of the flight before at ``tau_b``, the same of
    the flight after at ``tau_a``) (:meth:`FlightModelFit.coef_sensitivity`). The coefficients are shared by every
    flight, so their error moves every impact's COR the same way: left out, the sigmas held only the scatter and a
    drag's 2-sigma coverage was 0.53-1.00 over seeds (z mean -1.7..+1.4). Empty where the model has no flight
    term or their covariance is not finite (a coefficient the flights do not determine)."""
    flights = model.flights
    cov = np.asarray(getattr(flights, "cov", np.zeros((0, 0))), dtype=float)
    empty = (np.zeros((0, 0)), (np.zeros(0), np.zeros(0)), (np.zeros(0), np.zeros(0)))
    if cov.size == 0 or not np.all(np.isfinite(cov)) or not hasattr(flights, "coef_sensitivity"):
        return empty
    before = flights.coef_sensitivity(kb, meas.flights[kb].tau_s, tau_b, meas.mass_kg)
    after = flights.coef_sensitivity(ka, meas.flights[ka].tau_s, tau_a, meas.mass_kg)
    return cov, before, after


def impact_stds(meas: Measured, model: FittedModel, j: int) -> tuple[float, float]:
    """1-sigma (t_std_s, cor_std) of the model's impact j (index into ``model.impacts``), first order.

    Independent inputs: each flight's state (y0, v0) (:func:`_flight_state_cov`), the structure fit's
    parameters (coefficients and frequency) and the flight force coefficients theta shared by every flight
    (:func:`_coef_terms`: each flight's state re-fitted as theta moves). The model flight k is
    y_k(t) = y0_k + v0_k tau + (terms known given the force law), so a change (dy0, dv0) moves its position by
    dy0 + dv0 tau and its velocity by dv0. The impact time solves y_b(t) = y_a(t):
    dt = -(dy_b - dy_a) / (v_b - v_a); velocities then move with their accelerations a_b, a_a, a_s.
    e = -(v_a - v_s)/(v_b - v_s) gives de/dv_a = -1/(v_b - v_s),
    de/dv_b = (v_a - v_s)/(v_b - v_s)^2, de/dv_s = (v_b - v_a)/(v_b - v_s)^2."""
    imps = model.impacts
    imp = meas.impacts[int(imps.index[j])]
    kb, ka = imp.flight_before, imp.flight_after
    t = float(imps.t_s[j])
    vb, va, vs = float(imps.v_before[j]), float(imps.v_after[j]), float(imps.v_structure[j])
    tau_b = t - meas.flights[kb].t_ref_s
    tau_a = t - meas.flights[ka].t_ref_s
    yb = float(model.flights.state(kb, tau_b)[0])
    ya = float(model.flights.state(ka, tau_a)[0])
    ab = float(np.asarray(model.flight_accel(np.array([t]), np.array([yb]), np.array([vb]), meas.mass_kg))[0])
    aa = float(np.asarray(model.flight_accel(np.array([t]), np.array([ya]), np.array([va]), meas.mass_kg))[0])
    motion = model.motion
    a_s = float(motion.acceleration(t))
    # parameters: [y0_b, v0_b, y0_a, v0_a, structure..., flight force coefficients...]
    s_grad = _structure_velocity_gradient(model.structure, t)
    s_cov = model.structure.covariance(meas.t_s)
    n_s = s_grad.size
    c_cov, (dy_b, dv_b), (dy_a, dv_a) = _coef_terms(meas, model, kb, ka, tau_b, tau_a)
    n_c = dy_b.size
    n = 4 + n_s + n_c
    cov = np.zeros((n, n))
    cov[:2, :2] = _flight_state_cov(meas, model, kb)
    cov[2:4, 2:4] = _flight_state_cov(meas, model, ka)
    cov[4:4 + n_s, 4:4 + n_s] = s_cov
    cov[4 + n_s:, 4 + n_s:] = c_cov
    dv = vb - va
    g_t = np.zeros(n)
    g_t[:4] = np.array([-1.0, -tau_b, 1.0, tau_a]) / dv
    g_t[4 + n_s:] = -(dy_b - dy_a) / dv
    g_vb = np.zeros(n)
    g_vb[1] = 1.0
    g_vb[4 + n_s:] = dv_b
    g_vb += ab * g_t
    g_va = np.zeros(n)
    g_va[3] = 1.0
    g_va[4 + n_s:] = dv_a
    g_va += aa * g_t
    g_vs = np.zeros(n)
    g_vs[4:4 + n_s] = s_grad
    g_vs += a_s * g_t
    den = vb - vs
    g_e = (-1.0 / den) * g_va + ((va - vs) / den ** 2) * g_vb + ((vb - va) / den ** 2) * g_vs
    var_t = float(g_t @ cov @ g_t)
    var_e = float(g_e @ cov @ g_e)
    return math.sqrt(max(var_t, 0.0)), math.sqrt(max(var_e, 0.0))


def reidentify_impacts(meas: Measured, model: FittedModel) -> list[Impact]:
    """Every impact that ``model`` sees from both sides (a fitted flight before and after it), measured
    under ``model`` (its ``impacts``, computed by :func:`~vibro_discrepancy.fitting.recompute_impacts`),
    with propagated stds: the identified :class:`Impact` with ``t_s``, ``t_std_s``, ``v_*``, ``cor`` and
    ``cor_std`` re-measured (SI, + up) and ``t_paper_s`` the identification's time, which names it. Impacts
    with a side missing are left out (they keep the identification's values)."""
    out = []
    imps = model.impacts
    for j in range(imps.index.size):
        imp = meas.impacts[int(imps.index[j])]
        if imp.flight_before is None or imp.flight_after is None:
            continue
        if not all(math.isfinite(float(x[j])) for x in (imps.t_s, imps.v_before, imps.v_after, imps.v_structure,
                                                         imps.cor)):
            continue
        try:
            t_std, cor_std = impact_stds(meas, model, j)
        except (np.linalg.LinAlgError, ValueError, ZeroDivisionError):
            continue  # no uncertainty, no claim: the impact keeps the identification's values
        out.append(replace(imp, t_paper_s=float(imp.t_s), t_s=float(imps.t_s[j]), t_std_s=t_std,
                           v_ball_before_mps=float(imps.v_before[j]), v_ball_after_mps=float(imps.v_after[j]),
                           v_structure_mps=float(imps.v_structure[j]), cor=float(imps.cor[j]), cor_std=cor_std))
    return out


@dataclass(frozen=True)
class StructureMisfit:
    """How far a model's structure velocity is from the measured structure's at one time: ``dv_mps`` (m/s),
    its statistical 1-sigma ``std_mps`` (the local fit's noise), and ``model_std_mps``, how much it rests on the
    local model (zero where the drive does not change within the window)."""

    dv_mps: float
    std_mps: float
    model_std_mps: float = 0.0

    @property
    def total_std_mps(self) -> float:
        return math.hypot(self.std_mps, self.model_std_mps)


def structure_misfit(meas: Measured, motion, t_s: float) -> StructureMisfit:
    """How far the final model's structure velocity at ``t_s`` is from the measured structure's, and its 1-sigma
    std. The final model's residual r = Y_measured - Y_model over the frames within
    :data:`LOCAL_HALF_WINDOW_PERIODS` drive periods of ``t_s`` is fitted with
    c0 + c1 tau + (a + a1 tau) sin(w tau) + (b + b1 tau) cos(w tau), tau = t - t_s: an offset, a slow drift, and
    the part of the drive the model's sine misses there (an amplitude or phase that changed), itself changing
    linearly across the window so that an impact inside a ramp of the drive is measured too; its slope at
    tau = 0, c1 + w a + b1, is the velocity misfit, with the fit's std and, as ``model_std_mps``, its difference
    from the same fit without the linear change (a1 = b1 = 0): where the drive changes within the window, how
    much the answer rests on the local model. NaN when fewer than 12 frames."""
    sel = np.abs(meas.t_s - t_s) <= LOCAL_HALF_WINDOW_PERIODS / meas.frequency_hz
    if np.count_nonzero(sel) < 12:
        return StructureMisfit(math.nan, math.nan)
    tau = meas.t_s[sel] - t_s
    w = 2.0 * math.pi * meas.frequency_hz
    r = meas.structure_m[sel] - np.asarray(motion.position(meas.t_s[sel]), dtype=float)
    dv, dv_std = local_sine_slope(tau, r, w, ramp=True)
    dv_flat, _ = local_sine_slope(tau, r, w)
    return StructureMisfit(dv, dv_std, abs(dv - dv_flat))


def cor_shift_of_misfit(imp: Impact, dv_mps: float) -> float:
    """The COR error (Eq. 16) a structure velocity error ``dv_mps`` makes at impact ``imp``:
    de/dv_s = (v_before - v_after) / (v_before - v_s)^2."""
    vb, va, vs = imp.v_ball_before_mps, imp.v_ball_after_mps, imp.v_structure_mps
    return (vb - va) / (vb - vs) ** 2 * dv_mps


def with_local_structure(meas: Measured, model: FittedModel, impact: Impact) -> tuple[Impact, LocalStructure | None]:
    """``impact`` (re-measured under ``model``, :func:`reidentify_impacts`) as it stands when the final model's
    structure follows the measured structure there: the structure velocity misfit (:func:`structure_misfit`)
    carried into the COR within 3 of its statistical sigmas or :data:`COR_SUPPORT_FLOOR`; then (impact, None).
    Else the final model's one structure fit does not follow the structure at this impact (a drive whose
    amplitude or phase moved during the take) and the impact is measured with the structure velocity of the
    local fit: the model's plus the misfit, the model's flight law kept for the ball (Eq. 16 again, its std
    widened by the misfit's, the part that rests on the local model included); returns (that impact, the
    :class:`LocalStructure` record saying so)."""
    misfit = structure_misfit(meas, model.motion, float(impact.t_s))
    if not math.isfinite(misfit.dv_mps):
        return impact, None
    shift = cor_shift_of_misfit(impact, misfit.dv_mps)
    if abs(shift) <= max(3.0 * abs(cor_shift_of_misfit(impact, misfit.std_mps)), COR_SUPPORT_FLOOR):
        return impact, None
    v_s = impact.v_structure_mps + misfit.dv_mps
    cor = -(impact.v_ball_after_mps - v_s) / (impact.v_ball_before_mps - v_s)
    cor_std = math.hypot(impact.cor_std or 0.0, cor_shift_of_misfit(impact, misfit.total_std_mps))
    local = replace(impact, v_structure_mps=v_s, cor=cor, cor_std=cor_std)
    return local, LocalStructure(t_paper_s=float(impact.t_paper_s), cor_global=float(impact.cor),
                                 cor_shift=float(cor - impact.cor), structure_velocity_misfit_mps=misfit.dv_mps)


def impact_slopes(meas: Measured, model: FittedModel, impact: Impact) -> ImpactSlopes:
    """What ``model`` leaves in its residuals at ``impact`` (re-measured, :func:`reidentify_impacts`): the slopes
    (m/s) of the smooth part of its flights' residuals before and after (:func:`flight_residual_slope`) and of its
    structure's (:func:`structure_misfit`), each with its sigma (:mod:`vibro_model.model_error`)."""
    residuals = getattr(model.flights, "residuals", None)
    sides = []
    for k in (impact.flight_before, impact.flight_after):
        fl = meas.flights[k] if k is not None else None
        r = np.asarray(residuals[k], dtype=float) if fl is not None and residuals is not None else None
        ok = r is not None and len(residuals) == len(meas.flights) and r.shape == fl.tau_s.shape
        sides.append(flight_residual_slope(fl.tau_s, r, float(impact.t_s) - fl.t_ref_s) if ok else (math.nan, math.nan))
    misfit = structure_misfit(meas, model.motion, float(impact.t_s))
    return ImpactSlopes(plate=impact.plate, before=sides[0], after=sides[1],
                        structure=(misfit.dv_mps, misfit.std_mps))


def with_model_error(impact: Impact, errors: ModelError, structure: bool) -> Impact:
    """``impact`` with its COR sigma widened by what the final model leaves in its residuals at impacts of its
    kind (:class:`vibro_model.model_error.ModelError`; ``structure`` False: its structure velocity came from a
    local fit, whose own sigma it carries already)."""
    var = errors.cor_variance(impact.plate, impact.v_ball_before_mps, impact.v_ball_after_mps,
                              impact.v_structure_mps, structure)
    if var <= 0:
        return replace(impact, cor_std_model=None)
    return replace(impact, cor_std=math.sqrt((impact.cor_std or 0.0) ** 2 + var), cor_std_model=math.sqrt(var))


def reidentification(findings: Iterable[object], run) -> Reidentification:
    """The re-identification stage of the results assembler (:class:`vibro_model.assemble.Reidentification`):
    the impacts of ``run`` (a :class:`~vibro_discrepancy.engine.DiscrepancyRun` or None) measured again under
    its final model when one of ``findings`` changes how the impacts are measured, with the structure velocity of
    a local fit where the final model's structure does not follow the measured one (:func:`with_local_structure`);
    else none (every impact keeps the identification's values, ``cor_method`` "paper")."""
    effects = measurement_effects(findings)
    if run is None or run.final is None or run.measured is None:
        return Reidentification()
    if not effects:
        return Reidentification(friction=friction_correction(run, effects))
    impacts, local = [], []
    remeasured = reidentify_impacts(run.measured, run.final)
    errors = ModelError.of([impact_slopes(run.measured, run.final, imp) for imp in remeasured])
    for imp in remeasured:
        measured, note = with_local_structure(run.measured, run.final, imp)
        impacts.append(with_model_error(measured, errors, structure=note is None))
        local += [note] if note is not None else []
    return Reidentification(effects=tuple(effects), impacts=impacts, local_structure=local,
                            friction=friction_correction(run, effects))


def scale_friction_correction(run) -> FrictionCorrection | None:
    """The constant force the image scale's error puts into every flight's Eq. 17 friction, where the discrepancy
    analysis took the flights' apparent gravity as the scale's (``instrument_scale`` absorbed,
    :mod:`.instrument_scale`): Eq. 17 measures F = m (a + g) against the nominal g while the flights fall at
    g_scale = g (1 + e), so F holds m (g - g_scale) besides the friction (to first order in e). None otherwise."""
    scale = (getattr(run.result, "details", None) or {}).get("instrument_scale") or {}
    g_nom, g_used = scale.get("nominal_gravity_mps2"), scale.get("gravity_used_mps2")
    if not scale.get("absorbed") or g_nom is None or g_used is None or g_used == g_nom:
        return None
    force = float(run.measured.mass_kg) * (float(g_nom) - float(g_used))
    words = (f"friction_n of every free flight corrected for the image scale (instrument_scale: the flights fall at "
             f"{g_used:.4g} m/s^2 against g {g_nom:.4g} m/s^2 along the axis, the scale's error): Eq. 17 against g "
             f"holds m (g - g_scale) = {force:.3g} N, subtracted; friction_paper_n keeps the Eq. 17 value")
    return FrictionCorrection(effect="instrument_scale", force_n=force, force_std_n=0.0, words=words)


def friction_correction(run, effects: Sequence[str]) -> FrictionCorrection | None:
    """What the results take out of every flight's Eq. 17 friction: an undeclared tilt's force
    (:func:`tilt_friction_correction`, with ``gravity_tilt`` among ``effects``) and the image scale's
    (:func:`scale_friction_correction`), summed; None when neither."""
    tilt = tilt_friction_correction(run.measured, run.final) if "gravity_tilt" in effects else None
    scale = scale_friction_correction(run)
    if tilt is None or scale is None:
        return tilt or scale
    return FrictionCorrection(effect=f"{tilt.effect}+{scale.effect}", force_n=tilt.force_n + scale.force_n,
                              force_std_n=tilt.force_std_n, words=f"{tilt.words}; {scale.words}")


def tilt_friction_correction(meas: Measured, model: FittedModel) -> FrictionCorrection | None:
    """The force an undeclared tilt puts into every flight's Eq. 17 friction: the final model's ``gravity_tilt``
    acceleration change c (up) times the ball's mass, m c (N), with its sigma; None when the model has no tilt.
    Eq. 17 measures F = m (a + g cos theta) against the declared tilt theta; with the axis truly at theta_total
    every flight falls at g cos(theta_total) = g cos(theta) - c, so F holds m c besides the friction."""
    names = model.flights.names
    if "gravity_tilt" not in names:
        return None
    k = names.index("gravity_tilt")
    c = float(model.flights.coefs[k])
    var = float(model.flights.cov[k, k]) if model.flights.cov.size else 0.0
    sd = math.sqrt(var) if math.isfinite(var) and var > 0 else 0.0
    m = float(meas.mass_kg)
    total = model.tilt_deg
    words = (f"friction_n of every free flight corrected for the axis' undeclared tilt (gravity_tilt: the axis at "
             f"{total:.2f} deg from vertical, setup.axis_tilt_deg {meas.axis_tilt_deg:g} deg): Eq. 17 against the "
             f"declared gravity {meas.g_mps2:.3f} m/s^2 holds the tilt's constant force m c = {m * c:.3g} N "
             f"({m * c / (m * G_MPS2):+.3g} m g), subtracted; friction_paper_n keeps the Eq. 17 value")
    return FrictionCorrection(effect="gravity_tilt", force_n=m * c, force_std_n=m * sd, words=words)


def reidentified_from_impacts(doc: ResultsDocument, corrected: Iterable[Impact]) -> list[Impact]:
    """The re-identified impacts as a graph run carries them (the ``discrepancy`` node's
    ``vibro/impacts_final_model`` messages, converted to :class:`Impact`), matched by index to ``doc``'s
    identified impacts, whose time becomes their ``t_paper_s`` (the name :func:`apply_reidentification`
    matches by); an index ``doc`` does not hold is dropped."""
    t_identified = {i.index: i.t_s for i in doc.impacts if i.t_s is not None}
    out = []
    for c in corrected:
        if c.index not in t_identified or None in (c.t_s, c.cor, c.v_ball_before_mps, c.v_ball_after_mps,
                                                   c.v_structure_mps):
            continue
        out.append(replace(c, t_paper_s=t_identified[c.index]))
    return out
