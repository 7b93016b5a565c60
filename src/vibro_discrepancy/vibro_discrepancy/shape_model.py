"""A located out-of-catalogue shape, modelled: the ``unexplained`` finding's shape fitted and simulated.

The shape tests (:mod:`.shape` for the flights, :mod:`.systematic` for the CORs) locate what the final
catalogue model leaves and describe its shape. Two of those shapes are functions vibro can parametrise, so
(as a located structure tone is, :mod:`.tone`) they are fitted against the measured data with the machinery
the catalogue effects use and the model with them is simulated; the finding stays ``unexplained`` (no
catalogue term, no ``parameters``) and carries the fit as ``shape_model``:

- **position force** (:func:`fit_position_force`): a flight force that depends on the ball's distance d from
  the lower plate and not on its direction of motion, the exponential the shape check names,

      y'' = -g + sum_m theta_m basis_m(v) + A exp(-d / L),   d = (ball - structure) - lower contact level >= 0

  fitted like the catalogue's flight terms (:func:`vibro_discrepancy.fitting.fit_flights`: every flight's
  state free and projected out, the terms' double integrals along the model's own histories, a fixed point
  over the histories, ``PASSES`` passes), with A linear and the decay L by a 1-D search of the sum of
  squares (grid ``DECAYS_MM``, then a bounded refinement in log L: variable projection). The parameters'
  stds come from the Gauss-Newton Jacobian (sigma^2 (J^T J)^-1, sigma^2 = sse / dof). The catalogue flight
  terms the chain chose are fitted beside it and each is kept only when the data still need it with the
  shape in the model (chi^2 against the ball's noise floor at ``select.ALPHA`` and ``MIN_EXPLAINED_SIGMA``
  noise floors per frame explained, the rules every catalogue term passes): a Coulomb friction that only
  absorbed part of the position force is dropped, one that is really there stays. Simulated with
  :class:`vibro_sim.forces.PositionForce` (the same law class the synthetic rig uses; the fit is
  never told its parameters) on top of the kept catalogue force. Judged by D_r (its flights change).
- **COR parity** (:func:`fit_cor_parity`): the COR of one plate alternating on its successive impacts
  (:func:`vibro_discrepancy.systematic.parity_signs`), e_i = X_i c + s x_i with x_i = +-1 on that plate's
  impacts (+1 on its first), 0 on the other, X the columns of a COR law (constant, per plate, or speed):
  ordinary least squares of the CORs measured under the model, the law's columns beside the parity chosen
  by F-tests (``select.ALPHA_COR`` and ``MIN_COR_RMS``, the COR laws' rules). D_r cannot judge a COR law
  (it replays the measured velocity after each impact); the parity model is judged by D_i
  (:func:`impact_restarted_run`): each flight restarted from the measured state *before* the impact that
  opens it, that impact's COR from the model, on the same Eq. 18 scale, and by the share of the per-impact
  COR variance it explains (``cor_variance_share``, as a catalogue COR law).

A shape that the data do not let vibro parametrise is not modelled, or not kept: the position force is tried
when the residual beyond the chain's flight terms depends on the position (the shape check's ``position``
coordinate) and kept only when, beside the catalogue terms it keeps, the exponential explains ``EXP_SHARE`` of
what free position bins explain and no part that changes sign with the direction of motion is left
(:func:`position_form_check`; a real Coulomb friction beside it takes its constant direction-dependent part);
a trend or step of the COR is not a parity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
from scipy.optimize import minimize_scalar, nnls

from vibro_discrepancy.data import Measured
from vibro_discrepancy.fitting import (
    CorModelFit,
    FlightModelFit,
    ImpactSet,
    _cumtrapz,
    fit_cor,
    ols_cor_fit,
    recompute_impacts,
)
from vibro_discrepancy.library import FlightTerm, cor_values, restitution_law
from vibro_discrepancy.model import COR_TERMS, FittedModel, model_plate_levels
from vibro_discrepancy.runs import FullRun
from vibro_discrepancy.select import ALPHA, ALPHA_COR, MIN_COR_RMS, MIN_EXPLAINED_SIGMA, law_variance_share
from vibro_discrepancy.shape import EXP_SHARE, column_rank, ols_fit, position_bins
from vibro_discrepancy.systematic import parity_signs
from vibro_model.constants import G_MPS2
from vibro_model.tail_probability import chi2_sf, f_sf
from vibro_sim.deviation import Restart, restarted_deviation
from vibro_sim.forces import PositionForce
from vibro_sim.restitution import RestitutionLaw

PASSES = 3                                                           # fixed point over the flight histories
DECAYS_MM = tuple(float(x) for x in np.geomspace(0.3, 30.0, 25))     # the decay's grid (as :mod:`.shape`)
POSITION_KIND = "position_force"
PARITY_KIND = "cor_parity"
#: the shape models' names in a model's label (never a catalogue effect name)
LABELS = {POSITION_KIND: "position_force_shape", PARITY_KIND: "cor_parity_shape"}


# ---------------------------------------------------------------- the model with a shape
@dataclass
class PositionShape:
    """A + up (m/s^2) at contact with the lower plate, decaying over ``decay_m`` with the distance from it;
    ``lower_m`` the lower plate's contact level (ball - structure, DIC frame), ``free_play_m`` the model's."""

    accel_at_contact_mps2: float
    decay_m: float
    lower_m: float
    free_play_m: float
    mass_kg: float

    def accel(self, rel_m) -> np.ndarray:
        d = np.clip(np.asarray(rel_m, dtype=float) - self.lower_m, 0.0, None)
        return self.accel_at_contact_mps2 * np.exp(-d / self.decay_m)


@dataclass(kw_only=True)
class ParityShape:
    """One plate's COR alternates: the law's value + ``step`` x sign (+1 on the plate's first impact);
    ``signs`` per impact index (into :attr:`Measured.impacts`); ``first_sign`` of the first impact of the
    plate that a free-running replay meets."""

    plate: str
    base_kind: str
    base_coefs: np.ndarray
    step: float
    signs: dict[int, float]
    first_sign: float = 1.0


class ParityRestitution(RestitutionLaw):
    """A simulation's COR law with the parity: the base law's COR, and on ``plate`` + ``step`` x a sign that
    flips on each of its impacts the simulation meets (``first_sign`` on the first), clipped to [0, 1]. One
    instance per simulation (it counts the impacts it is asked about, each ``impact_index`` once)."""

    effect = PARITY_KIND

    def __init__(self, shape: ParityShape):
        self.shape = shape
        self.base = restitution_law(shape.base_kind, shape.base_coefs)
        self._signs: dict[int, float] = {}

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        e = self.base.cor(plate, v_rel_mps, impact_index)
        if plate != self.shape.plate:
            return e
        if impact_index not in self._signs:
            self._signs[impact_index] = self.shape.first_sign * (-1.0) ** len(self._signs)
        return float(min(1.0, max(0.0, e + self.shape.step * self._signs[impact_index])))


@dataclass(kw_only=True)
class ShapeModel(FittedModel):
    """A :class:`FittedModel` with a located shape modelled: a position force in flight, a COR parity, or
    both (None: that part is the catalogue model's)."""

    position: PositionShape | None = None
    parity: ParityShape | None = None

    @property
    def state_dependent(self) -> bool:   # type: ignore[override]
        return self.position is not None

    def flight_accel(self, t_s, y_m, v_mps, mass_kg: float) -> np.ndarray:
        a = self.accel(v_mps, mass_kg)
        if self.position is None:
            return a
        rel = np.asarray(y_m, dtype=float) - np.asarray(self.motion.position(np.asarray(t_s, dtype=float)), float)
        return a + self.position.accel(rel)

    def force_law(self):
        base = super().force_law()
        p = self.position
        if p is None:
            return base
        # PositionForce: F = base(v) - weight_fraction m g exp(-d / decay), d = y - Y_s + b in the cavity frame
        return PositionForce(self.motion, p.free_play_m, p.mass_kg, G_MPS2,
                             -p.accel_at_contact_mps2 / G_MPS2, 1e3 * p.decay_m, base)

    def restitution_law(self):
        if self.parity is None:
            return super().restitution_law()
        return ParityRestitution(self.parity)

    def cor_at(self, plates, speeds_mps, index=None) -> np.ndarray:
        if self.parity is None:
            return super().cor_at(plates, speeds_mps, index)
        par = self.parity
        e = cor_values(par.base_kind, par.base_coefs, plates, speeds_mps)
        if index is not None:
            x = np.array([par.signs.get(int(i), 0.0) if p == par.plate else 0.0
                          for i, p in zip(np.atleast_1d(index), np.atleast_1d(plates))])
            e = np.clip(e + par.step * x, 0.0, 1.0)
        return e

    def label(self) -> str:
        parts = self.structure.label_terms()
        parts += [t.effect for t, c in zip(self.flights.terms, self.flights.coefs)]
        if self.position is not None:
            parts.append(LABELS[POSITION_KIND])
        if self.parity is not None:
            if self.parity.base_kind != "none":
                parts.append(self.parity.base_kind)
            parts.append(LABELS[PARITY_KIND])
        elif self.cor.kind != "none":
            parts.append(self.cor.kind)
        return " + ".join(parts) or "baseline"


def as_shape_model(model: FittedModel) -> ShapeModel:
    """``model`` as a :class:`ShapeModel` (keeping a shape it already has)."""
    if isinstance(model, ShapeModel):
        return model
    return ShapeModel(structure=model.structure, flights=model.flights, impacts=model.impacts, cor=model.cor,
                      g_mps2=model.g_mps2, fixed_motion=model.fixed_motion, axis_tilt_deg=model.axis_tilt_deg)


# ---------------------------------------------------------------- position force: the fit
@dataclass(kw_only=True)
class PositionFit:
    """The flights fitted with the exponential position force beside the catalogue ``terms`` (module
    docstring): ``flights`` (the catalogue terms' coefficients and the histories with the force), A (m/s^2,
    + up), L (m) and their stds, the catalogue coefficients' stds, the fit's sum of squares and dof."""

    terms: tuple[FlightTerm, ...]
    flights: FlightModelFit
    accel_mps2: float
    accel_std_mps2: float
    decay_m: float
    decay_std_m: float
    term_stds: np.ndarray
    lower_m: float
    sse: float
    dof: int
    at_grid_end: bool = False


def _lower_level(meas: Measured, model: FittedModel) -> float:
    """The lower plate's contact level (ball - structure, DIC frame) as the model's runs place it: d = 0 there
    (:func:`model_plate_levels`: the cavity offset c0 and free play b put the lower plate at -(c0 + b))."""
    lv = model_plate_levels(meas, model)
    return -(lv["offset"] + lv["free_play"])


def _blocks(meas: Measured, hist, fns) -> list[np.ndarray]:
    """Per flight, the raw design (its fitted frames x len(fns)): each extra acceleration f(rel, v) (m/s^2 on
    the flight's grid) integrated twice from its reference time."""
    out = []
    for fl, (u, rel, v) in zip(meas.flights, hist):
        du = u[1] - u[0]
        cols = [np.interp(fl.tau_s, u, _cumtrapz(_cumtrapz(f(rel, v), du), du)) for f in fns]
        out.append(np.column_stack(cols) if cols else np.zeros((fl.tau_s.size, 0)))
    return out


def _projectors(meas: Measured) -> list[np.ndarray]:
    out = []
    for fl in meas.flights:
        L = np.column_stack([np.ones_like(fl.tau_s), fl.tau_s])
        out.append(np.linalg.qr(L)[0])
    return out


def _project(blocks: list[np.ndarray], Qs: list[np.ndarray]) -> np.ndarray:
    return np.vstack([X - Q @ (Q.T @ X) for X, Q in zip(blocks, Qs)])


def _solve(X_t: np.ndarray, x_p: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Least squares of r on [X_t (coefficients >= 0, as the catalogue's), x_p (free)]: (theta, A, sse)."""
    X = np.column_stack([X_t, x_p, -x_p])
    scale = np.sqrt(np.sum(X ** 2, axis=0))
    scale[scale == 0] = 1.0
    sol, _ = nnls(X / scale, r)
    c = sol / scale
    res = r - X @ c
    p = X_t.shape[1]
    return c[:p], float(c[p] - c[p + 1]), float(res @ res)


def _histories(meas: Measured, flights: FlightModelFit, model: FittedModel):
    """Per flight (u, ball - structure (m), ball velocity (m/s)) on the flights' grids."""
    out = []
    S = model.motion
    for k, fl in enumerate(meas.flights):
        u, v = flights.grids[k]
        y = flights.y0[k] + _cumtrapz(v, u[1] - u[0])
        out.append((u, y - np.asarray(S.position(fl.t_ref_s + u), float), v))
    return out


@dataclass(frozen=True)
class _PositionTarget:
    """What the position fit matches: per flight the projector ``Qs`` onto its [1, tau] (the free state) and
    the raw target ``r_raw`` = y + g tau^2 / 2 (m), and ``r`` the targets with the states projected out, stacked
    (m); ``g_mps2`` the gravity (m/s^2)."""

    Qs: list[np.ndarray]
    r_raw: list[np.ndarray]
    r: np.ndarray
    g_mps2: float


def _position_target(meas: Measured, g_mps2: float) -> _PositionTarget:
    """The flights' targets under gravity ``g_mps2`` (m/s^2), :class:`_PositionTarget`."""
    Qs = _projectors(meas)
    r_raw = [fl.y_m + 0.5 * g_mps2 * fl.tau_s ** 2 for fl in meas.flights]
    r = np.concatenate([y - Q @ (Q.T @ y) for y, Q in zip(r_raw, Qs)])
    return _PositionTarget(Qs, r_raw, r, g_mps2)


@dataclass(frozen=True)
class _PositionForce:
    """One pass's force: the catalogue ``terms``' coefficients ``theta`` (term units), A (m/s^2, + up), the decay
    L (m) and the lower plate's contact level (ball - structure, m) the distance is counted from."""

    terms: tuple[FlightTerm, ...]
    theta: np.ndarray
    accel_mps2: float
    decay_m: float
    lower_m: float


def _term_fns(terms: Sequence[FlightTerm], mass_kg: float) -> list:
    """Each catalogue term's acceleration basis as an extra-acceleration function f(rel (m), v (m/s))."""
    return [(lambda t: (lambda rel, v: t.basis(v, mass_kg)))(t) for t in terms]


def _exp_force(decay_m: float, lower_m: float):
    """exp(-d / L), d the distance (m) above the lower contact level ``lower_m``, as a function f(rel, v)."""
    return lambda rel, v: np.exp(-np.clip(rel - lower_m, 0.0, None) / decay_m)


def _best_decay(meas: Measured, hist, X_t: np.ndarray, target: _PositionTarget, lower_m: float) -> float:
    """The decay L (m) with the least sum of squares beside the projected catalogue columns ``X_t``: the grid
    ``DECAYS_MM``, then a bounded refinement in log L around its best point (kept only when it improves)."""
    def sse_at(log_L):
        x = _project(_blocks(meas, hist, [_exp_force(math.exp(log_L), lower_m)]), target.Qs)[:, 0]
        return _solve(X_t, x, target.r)[2]

    grid = [math.log(1e-3 * d) for d in DECAYS_MM]
    sses = [sse_at(x) for x in grid]
    j = int(np.argmin(sses))
    lo, hi = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
    best = minimize_scalar(sse_at, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    return math.exp(float(best.x) if best.fun <= sses[j] else grid[j])


def _position_flights(meas: Measured, hist, blocks: tuple[list, list], force: _PositionForce,
                      target: _PositionTarget) -> FlightModelFit:
    """The flights' states under ``force`` and their new velocity histories (as :func:`fit_flights`);
    ``blocks`` the raw designs (catalogue terms, the exponential) per flight on the histories ``hist``."""
    B_t, B_p = blocks
    terms, theta, A, L, lower = force.terms, force.theta, force.accel_mps2, force.decay_m, force.lower_m
    m, g, n = meas.mass_kg, target.g_mps2, len(meas.flights)
    y0, v0 = np.empty(n), np.empty(n)
    grids, sse_k, res_k = [], np.empty(n), []
    for k, (fl, (u, rel, v)) in enumerate(zip(meas.flights, hist)):
        Lk = np.column_stack([np.ones_like(fl.tau_s), fl.tau_s])
        rr = target.r_raw[k] - B_t[k] @ theta - A * B_p[k][:, 0]
        c, *_ = np.linalg.lstsq(Lk, rr, rcond=None)
        y0[k], v0[k] = c
        res = rr - Lk @ c
        res_k.append(res)
        sse_k[k] = float(res @ res)
        extra = A * np.exp(-np.clip(rel - lower, 0.0, None) / L)
        for t, th in zip(terms, theta):
            if th != 0.0:
                extra = extra + th * t.basis(v, m)
        grids.append((u, v0[k] - g * u + _cumtrapz(extra, u[1] - u[0])))
    n_points = int(sum(fl.t_s.size for fl in meas.flights))
    return FlightModelFit(terms=terms, coefs=np.asarray(theta, float), cov=np.zeros((len(terms), len(terms))),
                          y0=y0, v0=v0, sse=float(sse_k.sum()), n_points=n_points,
                          dof=max(n_points - 2 * n - len(terms) - 2, 1), flight_sse=sse_k,
                          flight_n=np.array([fl.t_s.size for fl in meas.flights]), residuals=res_k, grids=grids,
                          g_mps2=g)


def _position_pass(meas: Measured, cur: FittedModel, terms: tuple[FlightTerm, ...], target: _PositionTarget
                   ) -> tuple[FittedModel, _PositionForce]:
    """One pass of the fixed point: on ``cur``'s flight histories, the decay (:func:`_best_decay`), then A and the
    catalogue coefficients, then the flights' states and histories; (``cur`` with those flights and its impacts
    measured again under them, the force)."""
    hist = _histories(meas, cur.flights, cur)
    lower = _lower_level(meas, cur)
    B_t = _blocks(meas, hist, _term_fns(terms, meas.mass_kg))
    X_t = _project(B_t, target.Qs)
    L = _best_decay(meas, hist, X_t, target, lower)
    B_p = _blocks(meas, hist, [_exp_force(L, lower)])
    theta, A, _ = _solve(X_t, _project(B_p, target.Qs)[:, 0], target.r)
    force = _PositionForce(terms=terms, theta=theta, accel_mps2=A, decay_m=L, lower_m=lower)
    flights = _position_flights(meas, hist, (B_t, B_p), force, target)
    return replace(cur, flights=flights, impacts=recompute_impacts(meas, flights, cur.motion)), force


def _position_uncertainties(meas: Measured, cur: FittedModel, force: _PositionForce, target: _PositionTarget
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton on the projected Jacobian [active catalogue columns, d/dA, d/dL] at ``cur``'s histories
    (sigma^2 = sse / dof): (stds of those parameters, the catalogue coefficients' stds (NaN: inactive), their
    covariance (infinite variance: inactive))."""
    terms, theta, A, L, lower = force.terms, force.theta, force.accel_mps2, force.decay_m, force.lower_m
    flights, Qs = cur.flights, target.Qs
    hist = _histories(meas, flights, cur)
    x_p = _project(_blocks(meas, hist, [_exp_force(L, lower)]), Qs)[:, 0]
    x_l = _project(_blocks(meas, hist, [lambda rel, v: A * np.exp(-np.clip(rel - lower, 0.0, None) / L)
                                        * np.clip(rel - lower, 0.0, None) / L ** 2]), Qs)[:, 0]
    X_t = _project(_blocks(meas, hist, _term_fns(terms, meas.mass_kg)), Qs)
    active = [i for i in range(len(terms)) if theta[i] > 0]
    J = np.column_stack([X_t[:, active], x_p, x_l])
    s2 = flights.sse / flights.dof
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        cov = np.full((J.shape[1], J.shape[1]), np.nan)
    d = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    t_std = np.full(len(terms), np.nan)
    for j, i in enumerate(active):
        t_std[i] = d[j]
    t_cov = np.diag(np.where(np.isfinite(t_std), t_std, np.inf) ** 2) if len(terms) else np.zeros((0, 0))
    if active:
        t_cov[np.ix_(active, active)] = cov[:len(active), :len(active)]
    return d, t_std, t_cov


def fit_position_force(meas: Measured, model: FittedModel, terms: Sequence[FlightTerm]) -> PositionFit:
    """The flights with the exponential position force and the catalogue ``terms`` (module docstring), around
    ``model``'s structure motion, starting from its flight histories: ``PASSES`` passes of
    :func:`_position_pass`, then the parameters' stds (:func:`_position_uncertainties`)."""
    terms = tuple(terms)
    target = _position_target(meas, model.flights.g_mps2)
    cur, force = _position_pass(meas, model, terms, target)
    for _ in range(PASSES - 1):
        cur, force = _position_pass(meas, cur, terms, target)
    d, t_std, t_cov = _position_uncertainties(meas, cur, force, target)
    flights = replace(cur.flights, cov=t_cov)
    L = force.decay_m
    edge = math.log(L / (1e-3 * DECAYS_MM[0])) < 0.05 or math.log(1e-3 * DECAYS_MM[-1] / L) < 0.05
    return PositionFit(terms=terms, flights=flights, accel_mps2=float(force.accel_mps2), accel_std_mps2=float(d[-2]),
                       decay_m=float(L), decay_std_m=float(d[-1]), term_stds=t_std, lower_m=float(force.lower_m),
                       sse=flights.sse, dof=flights.dof, at_grid_end=bool(edge))


@dataclass
class TermTest:
    """A catalogue flight term tested beside the shape: the drop of the sum of squares without it, in noise
    floors (chi^2, 1 dof), its p-value, the explained RMS in noise floors, kept or not."""

    effect: str
    chi2: float
    p_value: float
    explained_x_noise: float
    kept: bool

    def to_dict(self) -> dict:
        return {"effect": self.effect, "chi2": self.chi2, "p_value": self.p_value,
                "explained_x_noise": self.explained_x_noise, "kept": self.kept}


def position_with_terms(meas: Measured, model: FittedModel, terms: Sequence[FlightTerm], sigma_m: float
                        ) -> tuple[PositionFit, list[TermTest]]:
    """The position force with the catalogue ``terms`` the data still need beside it (backward elimination:
    the least significant term that fails the catalogue's rules is dropped and the rest refitted, until every
    term left passes); the last test of every term."""
    kept = list(terms)
    fit = fit_position_force(meas, model, kept)
    tests: dict[str, TermTest] = {}
    sig2 = sigma_m ** 2
    n = fit.flights.n_points
    while kept:
        round_tests = []
        for t in kept:
            without = fit_position_force(meas, model, [x for x in kept if x is not t])
            drop = max(without.sse - fit.sse, 0.0)
            chi = drop / sig2
            p = chi2_sf(chi, 1)
            ex = math.sqrt(drop / max(n, 1)) / sigma_m
            round_tests.append((TermTest(t.effect, chi, p, ex, p < ALPHA and ex >= MIN_EXPLAINED_SIGMA), t, without))
        for tt, _, _ in round_tests:
            tests[tt.effect] = tt
        failing = [x for x in round_tests if not x[0].kept]
        if not failing:
            break
        worst = min(failing, key=lambda x: x[0].chi2)
        kept.remove(worst[1])
        fit = worst[2]
    return fit, [tests[t.effect] for t in terms if t.effect in tests]


def position_form_check(meas: Measured, model: FittedModel, fit: PositionFit, sigma_m: float) -> dict:
    """Is the fitted force the shape of the residual? On the fit's own histories, beside its kept catalogue
    terms: the exponential must explain ``EXP_SHARE`` of what ``N_BINS`` free bins of the distance from the
    lower plate explain (the rule by which :mod:`.shape` names an exponential), and the bins with opposite
    signs on rising and falling flights must find nothing beyond the model (chi^2 at ``ALPHA`` and
    ``MIN_EXPLAINED_SIGMA``: a direction-independent force). ``ok`` when both hold; ``reason`` else."""
    m, g = meas.mass_kg, fit.flights.g_mps2
    cur = replace(model, flights=fit.flights, impacts=recompute_impacts(meas, fit.flights, model.motion))
    hist = _histories(meas, fit.flights, cur)
    Qs = _projectors(meas)
    r = np.concatenate([(fl.y_m + 0.5 * g * fl.tau_s ** 2) - Q @ (Q.T @ (fl.y_m + 0.5 * g * fl.tau_s ** 2))
                        for fl, Q in zip(meas.flights, Qs)])
    lower, L = fit.lower_m, fit.decay_m
    _, even, odd = position_bins(lower, hist)
    X_t = _project(_blocks(meas, hist, [(lambda t: (lambda rel, v: t.basis(v, m)))(t) for t in fit.terms]), Qs)
    x_p = _project(_blocks(meas, hist, [lambda rel, v: np.exp(-np.clip(rel - lower, 0.0, None) / L)]), Qs)
    X_e = _project(_blocks(meas, hist, even), Qs)
    X_o = _project(_blocks(meas, hist, odd), Qs)
    sse_t = ols_fit(X_t, r)[1]
    sse_p = ols_fit(np.hstack([X_t, x_p]), r)[1]
    sse_e = ols_fit(np.hstack([X_t, X_e]), r)[1]
    share = (sse_t - sse_p) / (sse_t - sse_e) if sse_t > sse_e else float("nan")
    full = np.hstack([X_t, x_p, X_o])
    sse_o = ols_fit(full, r)[1]
    chi = max(sse_p - sse_o, 0.0) / sigma_m ** 2
    dof = max(column_rank(full) - column_rank(np.hstack([X_t, x_p])), 1)
    p = chi2_sf(chi, dof)
    ex = math.sqrt(max(sse_p - sse_o, 0.0) / max(r.size, 1)) / sigma_m
    odd_left = p < ALPHA and ex >= MIN_EXPLAINED_SIGMA
    reasons = []
    if not share >= EXP_SHARE:
        reasons.append(f"the exponential explains {100 * share:.0f} % of what free position bins explain (needs "
                       f"{100 * EXP_SHARE:.0f} %)")
    if odd_left:
        reasons.append(f"a part that changes sign with the direction of motion is left (chi2 = {chi:.3g}, "
                       f"{ex:.2f} noise floors)")
    return {"exponential_share_of_bins": share, "share_needed": EXP_SHARE,
            "direction_part_left": {"chi2": chi, "dof": dof, "p_value": p, "explained_x_noise": ex,
                                    "significant": odd_left},
            "ok": not reasons, "reason": "; ".join(reasons) or None}


def position_model(meas: Measured, model: FittedModel, fit: PositionFit) -> ShapeModel:
    """``model`` with the position fit's flights (the kept catalogue terms) and force, its impacts measured
    again under them and its COR law (the same kind) refitted on them."""
    imps = recompute_impacts(meas, fit.flights, model.motion)
    cor = fit_cor(imps, COR_TERMS[model.cor.kind], model.cor.kind) if model.cor.kind in COR_TERMS else model.cor
    sm = replace(as_shape_model(model), flights=fit.flights, impacts=imps, cor=cor)
    lv = model_plate_levels(meas, sm)
    sm.position = PositionShape(fit.accel_mps2, fit.decay_m, -(lv["offset"] + lv["free_play"]), lv["free_play"],
                                meas.mass_kg)
    if sm.parity is not None:
        sm.parity = None   # the CORs changed: a parity is fitted again on them
    return sm


def position_parameters(fit: PositionFit, meas: Measured) -> tuple[dict, dict]:
    """(parameters, stds): the acceleration and force at contact (+ up), the weight fraction towards the lower
    plate (-A / g), the decay length, and the kept catalogue terms' contract parameters."""
    g = fit.flights.g_mps2
    A, sA = fit.accel_mps2, fit.accel_std_mps2
    # a fraction of the ball's weight m g, whatever the axis' orientation (g along it may be 0)
    params = {"accel_at_contact_mps2": A, "force_at_contact_n": A * meas.mass_kg, "weight_fraction": -A / G_MPS2,
              "decay_mm": 1e3 * fit.decay_m}
    stds = {"accel_at_contact_mps2": sA, "force_at_contact_n": sA * meas.mass_kg, "weight_fraction": sA / G_MPS2,
            "decay_mm": 1e3 * fit.decay_std_m}
    for t, c, s in zip(fit.terms, fit.flights.coefs, fit.term_stds):
        p, sd = t.contract_parameters(float(c), float(s), meas.mass_kg, g, meas.axis_tilt_deg)
        params.update(p)
        stds.update(sd)
    return params, stds


def position_words(params: dict, stds: dict) -> str:
    """The modelled force in words."""
    wf, L = params["weight_fraction"], params["decay_mm"]
    towards = "towards the lower plate" if wf >= 0 else "away from the lower plate"
    return (f"a force {towards} of {100 * abs(wf):.1f} ± {100 * stds['weight_fraction']:.1f} % of the weight at "
            f"contact, A exp(-d/L) with the distance d from the lower plate, L = {L:.2f} ± {stds['decay_mm']:.2f} mm, "
            "the same on rising and falling flights")


# ---------------------------------------------------------------- COR parity: the fit
@dataclass
class ParityFit:
    """The CORs under the model fitted with a base COR law (``base_kind``) + the parity of ``plate``."""

    plate: str
    base_kind: str
    fit: CorModelFit
    signs: np.ndarray           # per impact of the ImpactSet: +-1 on the plate, 0 elsewhere
    tests: list[dict] = field(default_factory=list)


def _parity_fit(impacts: ImpactSet, kind: str, x: np.ndarray) -> CorModelFit:
    return ols_cor_fit(PARITY_KIND, np.column_stack([COR_TERMS[kind].columns(impacts.plate, impacts.speed), x]),
                       impacts.cor)


def fit_cor_parity(impacts: ImpactSet, plate: str, f0_hz: float, kinds: Sequence[str]) -> ParityFit | None:
    """The parity of ``plate`` on a COR law: ``"none"`` (one COR) unless a law of ``kinds`` beside the parity
    explains the CORs better (F-test at ALPHA_COR against the fit with it, and MIN_COR_RMS); the best such.
    None with fewer than 3 impacts per parity on the plate."""
    sel = impacts.plate == plate
    x = np.zeros(impacts.cor.size)
    x[sel] = parity_signs(impacts.t_s[sel], f0_hz)
    if min((x > 0).sum(), (x < 0).sum()) < 3:
        return None
    base = _parity_fit(impacts, "none", x)
    best, tests = ("none", base), []
    n = impacts.cor.size
    for kind in kinds:
        if kind == "none" or kind not in COR_TERMS:
            continue
        f = _parity_fit(impacts, kind, x)
        dp = f.p - base.p
        drop = max(base.sse - f.sse, 0.0)
        F = (drop / max(dp, 1)) / (f.sse / f.dof) if f.sse > 0 else float("inf")
        p = f_sf(F, max(dp, 1), f.dof)
        rms = math.sqrt(drop / max(n, 1))
        ok = p < ALPHA_COR and rms >= MIN_COR_RMS
        tests.append({"law": kind, "f_statistic": F, "p_value": p, "explained_rms": rms, "passes": ok})
        if ok and f.sse < best[1].sse:
            best = (kind, f)
    for t in tests:   # the law the parity sits on: the best of those that pass
        t["kept"] = t["law"] == best[0]
    return ParityFit(plate, best[0], best[1], x, tests)


def parity_parameters(pf: ParityFit, impacts: ImpactSet) -> tuple[dict, dict]:
    """(parameters, stds): the plate's COR on its first-counted and on its other impacts, the other plate's COR
    (at each plate's mean impact speed for a speed law) and a speed law's slope; linear in the coefficients."""
    c, cov = pf.fit.coefs, pf.fit.cov
    other = "top" if pf.plate == "bottom" else "bottom"

    def at(plate: str, sign: float) -> tuple[float, float]:
        sel = impacts.plate == plate
        speed = float(np.mean(impacts.speed[sel])) if sel.any() else float(np.mean(impacts.speed))
        row = np.append(COR_TERMS[pf.base_kind].columns(np.array([plate], dtype=object), np.array([speed]))[0], sign)
        return float(row @ c), float(math.sqrt(max(row @ cov @ row, 0.0)))

    params, stds = {}, {}
    for name, (plate, sign) in ((f"cor_{pf.plate}_first", (pf.plate, 1.0)),
                                (f"cor_{pf.plate}_second", (pf.plate, -1.0)), (f"cor_{other}", (other, 0.0))):
        params[name], stds[name] = at(plate, sign)
    if pf.base_kind == "velocity_dependent_restitution":
        params["slope_s_per_m"], stds["slope_s_per_m"] = float(c[1]), float(math.sqrt(max(cov[1, 1], 0.0)))
    return params, stds


def parity_words(pf: ParityFit, params: dict, stds: dict) -> str:
    pl = {"top": "upper", "bottom": "lower"}[pf.plate]
    a, b = f"cor_{pf.plate}_first", f"cor_{pf.plate}_second"
    return (f"the {pl} plate's COR alternating between {params[a]:.3f} ± {stds[a]:.3f} and "
            f"{params[b]:.3f} ± {stds[b]:.3f} on its successive impacts")


def parity_model(meas: Measured, model: FittedModel, pf: ParityFit) -> ShapeModel:
    """``model`` with the parity COR law (flights and structure kept); the sign of the first impact on the plate
    that the free-running replay (:func:`vibro_discrepancy.runs.full_run`) meets after its start."""
    imps = model.impacts
    signs = {int(i): float(s) for i, s, p in zip(imps.index, pf.signs, imps.plate) if p == pf.plate}
    k0 = next((k for k, fl in enumerate(meas.flights) if fl.open_impact is not None), None)
    t0 = -math.inf
    if k0 is not None:
        t_imp = dict(zip((int(i) for i in imps.index), (float(t) for t in imps.t_s)))
        t0 = t_imp.get(int(meas.flights[k0].open_impact), meas.flights[k0].t_ref_s)
    later = [(float(t), int(i)) for i, t, p in zip(imps.index, imps.t_s, imps.plate) if p == pf.plate and t > t0 + 1e-9]
    first = signs[min(later)[1]] if later else 1.0
    nb = COR_TERMS[pf.base_kind].columns(np.array(["top"], dtype=object), np.array([0.0])).shape[1]
    shape = ParityShape(plate=pf.plate, base_kind=pf.base_kind, base_coefs=np.asarray(pf.fit.coefs[:nb], float),
                        step=float(pf.fit.coefs[nb]), signs=signs, first_sign=first)
    sm = replace(as_shape_model(model), cor=pf.fit)
    sm.parity = shape
    return sm


def impact_restarted_run(meas: Measured, model: FittedModel) -> FullRun:
    """D_i of ``model`` (module docstring): as :func:`vibro_discrepancy.runs.restarted_run`, but each flight
    that an impact with a fitted flight before it opens starts with the velocity the model's COR gives that
    impact, v_after = v_s - e (v_before - v_s) (Eq. 16), from the model's impact time, position, velocity
    before and structure velocity; the other flights are left out."""
    try:
        lv = model_plate_levels(meas, model)
        imps = model.impacts
        row = {int(i): j for j, i in enumerate(imps.index)}
        e = model.cor_at(imps.plate, imps.speed, imps.index)
        restarts = []
        for k, fl in enumerate(meas.flights):
            i = fl.open_impact
            if i is None or int(i) not in row or meas.impacts[int(i)].flight_before is None:
                continue
            j = row[int(i)]
            t0 = float(imps.t_s[j])
            y0 = float(model.flights.state(k, t0 - fl.t_ref_s)[0])
            vs, vb = float(imps.v_structure[j]), float(imps.v_before[j])
            t1 = fl.t_end_s if fl.close_impact is not None else float(fl.t_s[-1])
            restarts.append(Restart(t0, t1, y0, vs - float(e[j]) * (vb - vs)))
        r = restarted_deviation(meas.t_s, meas.ball_m, restarts, model.motion, model.cavity(meas, lv["free_play"]),
                                model.restitution_law(), model.force_law(), frame_offset_m=lv["offset"])
        return FullRun(r.t_s, r.simulated_m, r.measured_m, r.deviation)
    except Exception as exc:  # noqa: BLE001 - a model that cannot be simulated must not lose the analysis
        return FullRun(meas.t_s[:0], None, meas.ball_m[:0], None, f"{type(exc).__name__}: {exc}")


def cor_share(model: FittedModel) -> float | None:
    """The share of the per-impact COR variance beyond noise that ``model``'s COR law explains."""
    return law_variance_share(model.impacts, model.cor)


__all__ = ["DECAYS_MM", "LABELS", "PARITY_KIND", "POSITION_KIND", "ParityFit", "ParityRestitution", "ParityShape",
           "PositionFit", "PositionShape", "ShapeModel", "TermTest", "as_shape_model", "cor_share",
           "fit_cor_parity", "fit_position_force", "impact_restarted_run", "parity_model", "parity_parameters",
           "parity_words", "position_form_check", "position_model", "position_parameters", "position_with_terms",
           "position_words"]
