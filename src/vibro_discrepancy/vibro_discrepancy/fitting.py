"""Least-squares fits of the candidate terms to the measured data (SI units, DIC frame).

Flights: every free flight k has its own initial state (y0_k, v0_k at its reference time, the opening
impact) and all flights share gravity g and the coefficients theta of the chosen flight terms:

    y_k(tau) = y0_k + v0_k tau - g tau^2 / 2 + sum_m theta_m Phi_mk(tau),
    Phi_mk(tau) = int_0^tau int_0^s basis_m(v_k(u)) du ds

which is linear in (y0, v0, theta) for a given velocity history v_k(u). The velocity history starts
from the identified parabola and is updated from the fitted model (fixed point, 3 passes: the
neglected change of v from the extra force is second order). theta >= 0 (non-negative least squares
after projecting out each flight's [1, tau]): a force that speeds the ball up is not this physics. The one
exception is the tilt's change of gravity, bounded below by g_axis - g (:meth:`FlightTerm.lower_bound`): on a
rig declared tilted (g_axis = g cos theta < g) the true tilt may be smaller than declared, and on a horizontal
one the constant is a force along the axis either way (the bound is shifted out: NNLS on theta - bound).

Structure: B + sum_k (a_k sin k w t + b_k cos k w t) over the orders used, linear for a given
frequency, which is refined by a 1-D search (variable projection).

Impacts: e_i = -(v_after - v_s)/(v_before - v_s) (paper Eq. 16 with its sign) recomputed from the
fitted flight models and structure motion, then linear COR laws by least squares.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.optimize import minimize_scalar, nnls

from vibro_discrepancy.data import FlightSamples, Measured
from vibro_discrepancy.library import FlightTerm, ImpactTerm
from vibro_model.constants import G_MPS2
from vibro_model.kinematics import StructureKinematics

GRID_STEP_S = 2e-5
FIXED_POINT_PASSES = 3


# --- flights ---------------------------------------------------------------------------------------

@dataclass(kw_only=True)
class FlightModelFit:
    """Fit of the flights with a set of flight terms."""

    terms: tuple[FlightTerm, ...]
    coefs: np.ndarray          # theta (term units)
    cov: np.ndarray            # of theta, with sigma^2 = sse / dof
    y0: np.ndarray             # per flight (m)
    v0: np.ndarray             # per flight (m/s)
    sse: float                 # m^2
    n_points: int
    dof: int
    flight_sse: np.ndarray     # per flight (m^2)
    flight_n: np.ndarray
    residuals: list[np.ndarray] = field(default_factory=list)
    grids: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)  # (u, v(u)) per flight
    g_mps2: float = G_MPS2

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(t.effect for t in self.terms)

    def coef_of(self, effect: str) -> float:
        return float(self.coefs[self.names.index(effect)]) if effect in self.names else 0.0

    def coef_dict(self) -> dict[str, float]:
        return {t.effect: float(c) for t, c in zip(self.terms, self.coefs)}

    def velocity(self, k: int, tau_s) -> np.ndarray:
        """Model velocity of flight k at tau (s after its reference time), m/s."""
        return self.state(k, tau_s)[1]

    def state(self, k: int, tau_s) -> tuple[np.ndarray, np.ndarray]:
        """Model (position m, velocity m/s) of flight k at tau (s after its reference time); beyond the
        fitted grid a second-order Taylor step from its nearest end (used within ~1 ms of it)."""
        u, v = self.grids[k]
        du = u[1] - u[0]
        y = self.y0[k] + _cumtrapz(v, du)
        tau = np.asarray(tau_s, dtype=float)
        yi = np.interp(tau, u, y)
        vi = np.interp(tau, u, v)
        a0 = (v[1] - v[0]) / du
        a1 = (v[-1] - v[-2]) / du
        lo = tau < u[0]
        hi = tau > u[-1]
        d0 = tau - u[0]
        d1 = tau - u[-1]
        yi = np.where(lo, y[0] + v[0] * d0 + 0.5 * a0 * d0 ** 2, yi)
        vi = np.where(lo, v[0] + a0 * d0, vi)
        yi = np.where(hi, y[-1] + v[-1] * d1 + 0.5 * a1 * d1 ** 2, yi)
        vi = np.where(hi, v[-1] + a1 * d1, vi)
        return yi, vi

    def flight_rms(self) -> np.ndarray:
        return np.sqrt(self.flight_sse / np.maximum(self.flight_n, 1))

    def coef_sensitivity(self, k: int, tau_fit_s: np.ndarray, tau_s: float,
                         mass_kg: float) -> tuple[np.ndarray, np.ndarray]:
        """(dy/dtheta m, dv/dtheta m/s per unit coefficient) of flight k at ``tau_s`` (s after its reference time),
        its state (y0, v0) re-fitted to its samples at ``tau_fit_s`` as the coefficients move (first order, the
        velocity history held): the term's own double and single integral phi, psi, minus the straight line
        [1, tau] (L^T L)^-1 L^T phi(tau_fit) its state takes up. Empty arrays without terms."""
        if not self.terms:
            return np.zeros(0), np.zeros(0)
        u, v = self.grids[k]
        du = u[1] - u[0]
        tau_fit = np.asarray(tau_fit_s, dtype=float)
        L = np.column_stack([np.ones_like(tau_fit), tau_fit])
        dy, dv = np.empty(len(self.terms)), np.empty(len(self.terms))
        for j, term in enumerate(self.terms):
            a = term.basis(v, mass_kg)
            psi = _cumtrapz(a, du)
            phi = _cumtrapz(psi, du)
            state, *_ = np.linalg.lstsq(L, np.interp(tau_fit, u, phi), rcond=None)
            end = 0 if tau_s < u[0] else -1            # beyond the grid: a Taylor step from its nearest end
            d = tau_s - u[end] if (tau_s < u[0] or tau_s > u[-1]) else 0.0
            phi_at = np.interp(tau_s, u, phi) + psi[end] * d + 0.5 * a[end] * d * d
            psi_at = np.interp(tau_s, u, psi) + a[end] * d
            dy[j] = phi_at - (state[0] + state[1] * tau_s)
            dv[j] = psi_at - state[1]
        return dy, dv


def _accel_extra(terms: Sequence[FlightTerm], coefs: np.ndarray, v: np.ndarray, mass_kg: float) -> np.ndarray:
    out = np.zeros_like(v)
    for t, c in zip(terms, coefs):
        if c != 0.0:
            out = out + c * t.basis(v, mass_kg)
    return out


def _cumtrapz(y: np.ndarray, dx: float) -> np.ndarray:
    out = np.empty_like(y)
    out[0] = 0.0
    np.cumsum(0.5 * (y[1:] + y[:-1]) * dx, out=out[1:])
    return out


#: the integration grids alive (one per flight, read-only), shared by every fit of the same flights: the
#: candidate fits of a long recording then hold only their velocity histories (~400 B per frame each)
_GRIDS: weakref.WeakValueDictionary = weakref.WeakValueDictionary()


def _grid(fl: FlightSamples, extend_s: float = 0.0) -> np.ndarray:
    tau_max = max(float(fl.tau_s[-1]), fl.t_end_s - fl.t_ref_s) + extend_s
    n = max(int(math.ceil(tau_max / GRID_STEP_S)), 4)
    u = _GRIDS.get((tau_max, n))
    if u is None:
        u = np.linspace(0.0, tau_max, n + 1)
        u.flags.writeable = False
        _GRIDS[(tau_max, n)] = u
    return u


def fit_flights(meas: Measured, terms: Sequence[FlightTerm] = (), passes: int = FIXED_POINT_PASSES,
                g_mps2: float | None = None, fixed_coefs: Sequence[float] | None = None) -> FlightModelFit:
    """Fit the flights with gravity (``g_mps2``, default the measured data's g) plus ``terms``;
    ``fixed_coefs`` imposes the terms' coefficients (only the flight states are fitted then)."""
    g = meas.g_mps2 if g_mps2 is None else g_mps2
    terms = tuple(terms)
    p = len(terms)
    m = meas.mass_kg
    flights = meas.flights
    grids = [_grid(fl) for fl in flights]
    vels = [fl.v_nominal(fl.t_ref_s + u) for fl, u in zip(flights, grids)]
    coefs = np.zeros(p)
    for _ in range(max(1, passes) if p else 1):
        Xp, rp, locals_ = [], [], []
        for fl, u, v in zip(flights, grids, vels):
            tau = fl.tau_s
            du = u[1] - u[0]
            cols = []
            for t in terms:
                psi = _cumtrapz(t.basis(v, m), du)
                phi = _cumtrapz(psi, du)
                cols.append(np.interp(tau, u, phi))
            phi_m = np.column_stack(cols) if cols else np.zeros((tau.size, 0))
            r = fl.y_m + 0.5 * g * tau ** 2
            L = np.column_stack([np.ones_like(tau), tau])
            Q, _ = np.linalg.qr(L)
            Xp.append(phi_m - Q @ (Q.T @ phi_m))
            rp.append(r - Q @ (Q.T @ r))
            locals_.append((L, r, phi_m))
        X = np.vstack(Xp) if p else np.zeros((sum(x.shape[0] for x in Xp), 0))
        R = np.concatenate(rp)
        if p and fixed_coefs is not None:
            coefs = np.asarray(fixed_coefs, dtype=float)
        elif p:
            scale = np.sqrt(np.sum(X ** 2, axis=0))
            scale[scale == 0] = 1.0
            lower = np.array([t.lower_bound(g, meas.axis_tilt_deg) for t in terms])   # 0 but a tilted axis' tilt
            sol, _ = nnls(X / scale, R - X @ lower)
            coefs = sol / scale + lower
        # local states and the updated velocity history
        y0 = np.empty(len(flights))
        v0 = np.empty(len(flights))
        new_vels, sse_k, res_k = [], np.empty(len(flights)), []
        for k, (fl, u, v, (L, r, phi_m)) in enumerate(zip(flights, grids, vels, locals_)):
            rr = r - (phi_m @ coefs if p else 0.0)
            c, *_ = np.linalg.lstsq(L, rr, rcond=None)
            y0[k], v0[k] = c
            res = rr - L @ c
            res_k.append(res)
            sse_k[k] = float(res @ res)
            du = u[1] - u[0]
            new_vels.append(v0[k] - g * u + _cumtrapz(_accel_extra(terms, coefs, v, m), du))
        vels = new_vels
    n_points = int(sum(fl.t_s.size for fl in flights))
    dof = max(n_points - 2 * len(flights) - p, 1)
    sse = float(sse_k.sum())
    sigma2 = sse / dof
    if p:
        # covariance from the projected design of the final pass (active coefficients only)
        Xa = X
        try:
            cov = sigma2 * np.linalg.inv(Xa.T @ Xa)
        except np.linalg.LinAlgError:
            cov = np.full((p, p), np.inf)
    else:
        cov = np.zeros((0, 0))
    return FlightModelFit(terms=terms, coefs=coefs, cov=cov, y0=y0, v0=v0, sse=sse, n_points=n_points, dof=dof,
                          flight_sse=sse_k, flight_n=np.array([fl.t_s.size for fl in flights]), residuals=res_k,
                          grids=list(zip(grids, vels)), g_mps2=g)


# --- structure -------------------------------------------------------------------------------------

@dataclass(kw_only=True)
class StructureModelFit:
    """Y_s = B + sum over orders of (a_k sin k w t + b_k cos k w t), w = 2 pi f (m, s)."""

    orders: tuple[int, ...]
    frequency_hz: float
    coefs: np.ndarray          # [B, a_1, b_1, a_k, b_k ...]
    sse: float
    n_points: int
    dof: int
    residual: np.ndarray

    def _amp_phase(self, j: int) -> tuple[float, float]:
        a, b = self.coefs[1 + 2 * j], self.coefs[2 + 2 * j]
        return math.hypot(a, b), math.atan2(b, a)  # a sin x + b cos x = c sin(x + psi)

    def motion(self) -> StructureKinematics:
        """As a vibro_sim StructureKinematics (harmonic ratios/phases relative to the fundamental)."""
        A, phi = self._amp_phase(0)
        kw = {}
        for j, k in enumerate(self.orders[1:], start=1):
            c, psi = self._amp_phase(j)
            kw[f"h{k}_ratio"] = c / A if A > 0 else 0.0
            kw[f"h{k}_phase_rad"] = math.remainder(psi - k * phi, 2 * math.pi)
        return StructureKinematics(A, self.frequency_hz, phi, float(self.coefs[0]), **kw)

    def harmonic_amplitudes(self) -> dict[int, float]:
        """Amplitude (m) of each harmonic order beyond the fundamental."""
        return {k: self._amp_phase(j)[0] for j, k in enumerate(self.orders) if k > 1}

    @property
    def sigma(self) -> float:
        return math.sqrt(self.sse / self.dof)

    def label_terms(self) -> list[str]:
        """What this structure model adds to the pure sine, for the model's label."""
        extra = tuple(k for k in self.orders if k > 1)
        return ["structure_harmonics" + str(extra)] if extra else []

    #: the frequencies (Hz) at the end of :meth:`parameters`
    n_frequencies = 1

    def parameters(self) -> np.ndarray:
        """The fitted parameters [coefs..., frequency_hz] (m, Hz): the order of :meth:`jacobian`."""
        return np.append(np.asarray(self.coefs, dtype=float), float(self.frequency_hz))

    def velocity_with(self, params: np.ndarray, t_s: float) -> float:
        """dY_s/dt (m/s) at ``t_s`` with the parameters ``params`` (as :meth:`parameters`)."""
        c, w = params[:-1], 2 * math.pi * float(params[-1])
        return sum(k * w * (c[1 + 2 * j] * math.cos(k * w * t_s) - c[2 + 2 * j] * math.sin(k * w * t_s))
                   for j, k in enumerate(self.orders))

    def jacobian(self, t_s: np.ndarray) -> np.ndarray:
        """D Y_s(t) / d parameters (N x P, as :meth:`parameters`) at the fitted values."""
        t = np.asarray(t_s, dtype=float)
        c, f = np.asarray(self.coefs, dtype=float), float(self.frequency_hz)
        w = 2 * math.pi * f
        d_f = np.zeros_like(t)
        for j, k in enumerate(self.orders):
            a, b = c[1 + 2 * j], c[2 + 2 * j]
            d_f += 2 * math.pi * k * t * (a * np.cos(k * w * t) - b * np.sin(k * w * t))
        return np.column_stack([_design(t, f, self.orders), d_f])

    def covariance(self, t_s: np.ndarray) -> np.ndarray:
        """Covariance of :meth:`parameters` (Gauss-Newton on the fitted samples ``t_s``, sigma^2 = sse / dof);
        NaN when singular."""
        J = self.jacobian(t_s)
        try:
            return self.sigma ** 2 * np.linalg.inv(J.T @ J)
        except np.linalg.LinAlgError:
            return np.full((J.shape[1], J.shape[1]), np.nan)


def _design(t: np.ndarray, f: float, orders: Sequence[int]) -> np.ndarray:
    w = 2 * math.pi * f
    cols = [np.ones_like(t)]
    for k in orders:
        cols += [np.sin(k * w * t), np.cos(k * w * t)]
    return np.column_stack(cols)


def fit_structure_harmonics(t_s: np.ndarray, y_m: np.ndarray, f0_hz: float,
                            orders: Sequence[int] = (1,)) -> StructureModelFit:
    """Least squares of the structure track with the given harmonic orders (1 = the fundamental);
    the frequency is refined within +-0.2 % of ``f0_hz``."""
    t = np.asarray(t_s, dtype=float)
    y = np.asarray(y_m, dtype=float)
    orders = tuple(sorted(set((1,) + tuple(orders))))

    def sse(f):
        X = _design(t, f, orders)
        c, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ c
        return float(r @ r)

    span = 2e-3 * f0_hz
    res = minimize_scalar(sse, bounds=(f0_hz - span, f0_hz + span), method="bounded",
                          options={"xatol": 1e-9 * f0_hz})
    f = float(res.x)
    X = _design(t, f, orders)
    c, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ c
    n = t.size
    return StructureModelFit(orders=orders, frequency_hz=f, coefs=c, sse=float(r @ r), n_points=n,
                             dof=max(n - X.shape[1] - 1, 1), residual=r)


# --- impacts ---------------------------------------------------------------------------------------

@dataclass(kw_only=True)
class ImpactSet:
    """Per-impact quantities recomputed under a model (arrays over the usable impacts)."""

    index: np.ndarray          # into Measured.impacts
    t_s: np.ndarray
    plate: np.ndarray
    v_before: np.ndarray
    v_after: np.ndarray
    v_structure: np.ndarray
    cor: np.ndarray
    cor_std: np.ndarray        # the identified COR stds' noise share (Impact.cor_std_noise: model error out)

    @property
    def speed(self) -> np.ndarray:
        return np.abs(self.v_before - self.v_structure)


def impact_time(meas: Measured, flights: FlightModelFit, i: int) -> float:
    """Impact i's time under the flight model: where the model flights before and after it meet
    (Newton from the identified time; the identified time, from parabola fits, is biased when the
    flight force is not constant). The identified time when a side is missing or Newton strays > 1 ms."""
    imp = meas.impacts[i]
    kb, ka = imp.flight_before, imp.flight_after
    if kb is None or ka is None:
        return imp.t_s
    rb, ra = meas.flights[kb].t_ref_s, meas.flights[ka].t_ref_s
    t = imp.t_s
    for _ in range(4):
        yb, vb = flights.state(kb, t - rb)
        ya, va = flights.state(ka, t - ra)
        dv = float(vb - va)
        if abs(dv) < 1e-6:
            return imp.t_s
        t = t - float(yb - ya) / dv
    return t if abs(t - imp.t_s) < 1e-3 else imp.t_s


def recompute_impacts(meas: Measured, flights: FlightModelFit, structure: StructureKinematics) -> ImpactSet:
    """Impact times (:func:`impact_time`) and velocities from the fitted flight models on both sides
    and the structure model (plus a creeping plate's velocity, :meth:`Measured.plate_velocity_mps`); impacts
    without a fitted flight on one side keep the identified time and
    velocity there."""
    rows = []
    for imp in meas.impacts:
        vb, va = imp.v_ball_before_mps, imp.v_ball_after_mps
        t = impact_time(meas, flights, imp.index)
        if imp.flight_before is not None:
            fl = meas.flights[imp.flight_before]
            vb = float(flights.velocity(imp.flight_before, t - fl.t_ref_s))
        if imp.flight_after is not None:
            fl = meas.flights[imp.flight_after]
            va = float(flights.velocity(imp.flight_after, t - fl.t_ref_s))
        vs = float(structure.velocity(t)) + meas.plate_velocity_mps(imp.plate, t)   # a creeping plate's own
        den = vb - vs
        if abs(den) < 1e-6:
            continue
        e = -(va - vs) / den
        rows.append((imp.index, t, imp.plate, vb, va, vs, e, imp.cor_std_noise or 0.0))
    if not rows:
        z = np.zeros(0)
        return ImpactSet(index=z.astype(int), t_s=z, plate=np.array([], dtype=object), v_before=z, v_after=z,
                         v_structure=z, cor=z, cor_std=z)
    cols = list(zip(*rows))
    return ImpactSet(index=np.array(cols[0], dtype=int), t_s=np.array(cols[1]), plate=np.array(cols[2], dtype=object),
                     v_before=np.array(cols[3]), v_after=np.array(cols[4]), v_structure=np.array(cols[5]),
                     cor=np.array(cols[6]), cor_std=np.array(cols[7]))


@dataclass(kw_only=True)
class CorModelFit:
    kind: str                  # "none", "asymmetric_restitution", "velocity_dependent_restitution", "plate_and_speed"
    coefs: np.ndarray
    cov: np.ndarray
    sse: float
    n: int
    dof: int
    residual: np.ndarray

    @property
    def p(self) -> int:
        return self.coefs.size


def fit_cor(impacts: ImpactSet, term: ImpactTerm, kind: str) -> CorModelFit:
    """Ordinary least squares of the recomputed CORs with a linear COR law."""
    X = term.columns(impacts.plate, impacts.speed)
    return ols_cor_fit(kind, X, impacts.cor)


def ols_cor_fit(kind: str, X: np.ndarray, e: np.ndarray) -> CorModelFit:
    """Ordinary least squares of the CORs ``e`` on the columns ``X`` (one row per impact): coefficients, their
    covariance sigma^2 (X^T X)^-1 (infinite when X is singular), residuals."""
    n, p = X.shape
    if n == 0:
        return CorModelFit(kind=kind, coefs=np.zeros(p), cov=np.full((p, p), np.inf), sse=0.0, n=0, dof=1,
                           residual=np.zeros(0))
    c, *_ = np.linalg.lstsq(X, e, rcond=None)
    r = e - X @ c
    sse = float(r @ r)
    dof = max(n - p, 1)
    try:
        cov = (sse / dof) * np.linalg.inv(X.T @ X)
    except np.linalg.LinAlgError:
        cov = np.full((p, p), np.inf)
    return CorModelFit(kind=kind, coefs=c, cov=cov, sse=sse, n=n, dof=dof, residual=r)
