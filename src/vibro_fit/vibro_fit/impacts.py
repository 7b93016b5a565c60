"""Impact time (Eq. 15), plate, COR (Eq. 16 with its minus sign) and their uncertainties.

Conventions: positions mm (track displacements, positive up), times s (camera clock), velocities m/s.
COR e = -(v_b+ - v_s) / (v_b- - v_s), all at the impact time t_i.
The plate is "top" when the ball approaches it moving up relative to the structure (v_b- - v_s > 0).

Methods
-------
- ``paper``: t_i is the root of Eq. 15 (difference of the two flight parabolas) inside the gap between
  the last frame of the flight before and the first frame of the flight after; roots outside the gap are
  never used (no root inside -> no impact). The COR std is propagated to first order from the covariances
  of both flights and of the local structure fit (numerical Jacobian, central differences).
- ``joint``: better than the paper: the two flights are fitted together with the constraint that they
  meet *on the plate*, i.e. Y_b(t_i) - Y_s(t_i) = y_plate (the relative position of that plate, measured
  once from all the impacts of the recording). 5 parameters (t_i, v-, a-, v+, a+) instead of 6 plus one
  geometric constraint, which pins the extrapolated end points of both parabolas.
- ``finite_difference_cor``: the baseline the paper argues against: central differences of the track at
  the frames around the impact (for the benchmark only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from vibro_model.codec import none_if_nan
from vibro_model.results import Impact
from vibro_model.units import m_to_mm, mm_to_m

from .flight_fit import FlightFit
from .structure_fit import StructureFit, with_params


@dataclass
class ImpactFit(Impact):
    """One impact between flights ``flight_before`` and ``flight_after`` as the fit estimates it: the model
    :class:`~vibro_model.results.Impact` (SI; NaN where the fit gives no number) plus the fit context the
    joint refit and the plate levels use. :meth:`model` gives the plain Impact the results and messages carry."""

    y_rel_mm: float = math.nan                 # ball - structure displacement at t_i (track coordinates, mm)
    structure: StructureFit | None = None      # the local structure fit that gave v_structure

    def model(self) -> Impact:
        """The plain model Impact (NaN -> None: unknown)."""
        return Impact(index=int(self.index), t_s=none_if_nan(self.t_s), plate=self.plate, cor=none_if_nan(self.cor),
                      cor_std=none_if_nan(self.cor_std), v_ball_before_mps=none_if_nan(self.v_ball_before_mps),
                      v_ball_after_mps=none_if_nan(self.v_ball_after_mps),
                      v_structure_mps=none_if_nan(self.v_structure_mps),
                      t_std_s=none_if_nan(self.t_std_s), flight_before=int(self.flight_before),
                      flight_after=int(self.flight_after), method=self.method, in_gap=self.in_gap,
                      gap_lost_frames=self.gap_lost_frames, cor_std_model=self.cor_std_model)


def _shift(coef: np.ndarray, t_ref: float, t_new: float) -> tuple[float, float, float]:
    """Coefficients of A (t-t_ref)^2 + B (t-t_ref) + C re-expressed about t_new."""
    a, b, c = coef
    d = t_new - t_ref
    return a, 2.0 * a * d + b, (a * d + b) * d + c


def gap_root(p_coef: np.ndarray, p_ref: float, q_coef: np.ndarray, q_ref: float,
             t_lo: float, t_hi: float) -> float | None:
    """Eq. 15: the time in [t_lo, t_hi] where the two parabolas meet, or None (never a root outside)."""
    tm = 0.5 * (t_lo + t_hi)
    h = 0.5 * (t_hi - t_lo)
    pa, pb, pc = _shift(p_coef, p_ref, tm)
    qa, qb, qc = _shift(q_coef, q_ref, tm)
    al, be, ga = qa - pa, qb - pb, qc - pc
    roots: list[float] = []
    if abs(al) * h * h < 1e-12 * max(abs(be) * h, abs(ga), 1e-300):
        if be != 0:
            roots.append(-ga / be)
    else:
        disc = be * be - 4.0 * al * ga
        if disc < 0:
            return None
        sq = np.sqrt(disc)
        qq = -0.5 * (be + (sq if be >= 0 else -sq))
        if qq != 0:
            roots += [qq / al, ga / qq]
        else:
            roots.append(0.0)
    inside = [r for r in roots if -h <= r <= h]
    if not inside:
        return None
    return tm + min(inside, key=abs)


def _quantities(pc, p_ref, qc, q_ref, sp, s_fit: StructureFit, t_lo, t_hi):
    t_i = gap_root(pc, p_ref, qc, q_ref, t_lo, t_hi)
    if t_i is None:
        return None
    vm = mm_to_m(2.0 * pc[0] * (t_i - p_ref) + pc[1])
    vp = mm_to_m(2.0 * qc[0] * (t_i - q_ref) + qc[1])
    s = with_params(s_fit, sp) if sp is not None else s_fit
    vs = float(s.velocity_mps(t_i))
    return t_i, vm, vp, vs, -(vp - vs) / (vm - vs)


def central_jacobian(f, x0: np.ndarray, sd: np.ndarray, rel_step: float = 1e-3) -> np.ndarray:
    """Jacobian (outputs x parameters) of ``f`` (parameters -> 1-D array, or None where undefined) at ``x0`` by
    central differences, each parameter stepped by ``rel_step`` times its 1-sigma ``sd``: the first-order
    propagation of a fit's covariance. A parameter with sigma 0, or whose step leaves ``f`` undefined on either
    side, gives a zero column."""
    cols: dict[int, np.ndarray] = {}
    for j in range(x0.size):
        h = rel_step * sd[j] if sd[j] > 0 else 0.0
        if h == 0.0:
            continue
        outs = []
        for sgn in (1.0, -1.0):
            x = x0.copy()
            x[j] += sgn * h
            outs.append(f(x))
        if outs[0] is None or outs[1] is None:
            continue
        cols[j] = (np.asarray(outs[0], float) - np.asarray(outs[1], float)) / (2 * h)
    n_out = len(next(iter(cols.values()))) if cols else 0
    jac = np.zeros((n_out, x0.size))
    for j, col in cols.items():
        jac[:, j] = col
    return jac


def paper_impact(index: int, p: FlightFit, q: FlightFit, s_fit: StructureFit) -> ImpactFit | None:
    """Impact between fitted flights p (before) and q (after) with the paper's plain method, or None
    when the parabolas do not meet inside the gap or the relative velocity does not reverse."""
    t_lo, t_hi = p.t_end_s, q.t_start_s
    sp0 = np.asarray(s_fit.params_ref, float)
    base = _quantities(p.coef, p.t_ref_s, q.coef, q.t_ref_s, sp0, s_fit, t_lo=t_lo, t_hi=t_hi)
    if base is None:
        return None
    t_i, vm, vp, vs, e = base
    if (vm - vs) * (vp - vs) >= 0:
        return None
    # first-order propagation over x = [p.coef, q.coef, structure params]
    x0 = np.concatenate([p.coef, q.coef, sp0])
    scov = s_fit.cov_ref if s_fit.cov_ref is not None else np.zeros((4, 4))
    cov = np.zeros((10, 10))
    cov[:3, :3], cov[3:6, 3:6], cov[6:, 6:] = p.cov, q.cov, scov
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))

    def time_and_cor(x):
        r = _quantities(x[:3], p.t_ref_s, x[3:6], q.t_ref_s, x[6:], s_fit, t_lo=t_lo - 1.0, t_hi=t_hi + 1.0)
        return None if r is None else (r[0], r[4])

    jac = central_jacobian(time_and_cor, x0, sd)
    if jac.shape[0] == 0:
        jac = np.zeros((2, x0.size))
    var = jac @ cov @ jac.T
    y_rel = float(p.position_mm(t_i) - s_fit.position_mm(t_i))
    return ImpactFit(index=index, t_s=float(t_i), t_std_s=float(np.sqrt(max(var[0, 0], 0))),
                     plate="top" if vm - vs > 0 else "bottom", cor=float(e), cor_std=float(np.sqrt(max(var[1, 1], 0))),
                     v_ball_before_mps=float(vm), v_ball_after_mps=float(vp), v_structure_mps=float(vs),
                     y_rel_mm=y_rel, flight_before=p.index, flight_after=q.index, method="paper", structure=s_fit)


def joint_impact(est: ImpactFit, p: FlightFit, q: FlightFit, t_s: np.ndarray, y_mm: np.ndarray,
                 y_plate_mm: float, accel_priors: tuple | None = None, noise_mm: float | None = None
                 ) -> ImpactFit:
    """Refit the two flights around ``est`` jointly, constrained to meet on the plate at relative position
    ``y_plate_mm`` (mm, track coordinates). Starts from the paper estimate; returns a new estimate.

    ``accel_priors`` = ((mu_p, tau_p), (mu_q, tau_q)): optional Gaussian priors on the quadratic coefficient
    A (mm/s^2, half the acceleration) of each flight (mean and std over the recording's flights of the same
    direction: empirical-Bayes shrinkage of the per-flight friction), weighted with the position noise
    ``noise_mm``. Either prior may be None.
    """
    s_fit = est.structure
    tp, yp = t_s[p.frames], y_mm[p.frames]
    tq, yq = t_s[q.frames], y_mm[q.frames]
    t0 = est.t_s

    def model(th, sfit=s_fit):
        ti, vm, am, vp, ap = th
        ti = t0 + ti
        y0 = float(sfit.position_mm(ti)) + y_plate_mm
        dp, dq = tp - ti, tq - ti
        return y0 + vm * dp + am * dp * dp, y0 + vp * dq + ap * dq * dq

    priors = []
    if accel_priors is not None and noise_mm:
        for k, pr in zip((2, 4), accel_priors):
            if pr is not None and pr[1] > 0:
                priors.append((k, pr[0], noise_mm / pr[1]))

    def resid(th):
        mp, mq = model(th)
        extra = [w * (th[k] - mu) for k, mu, w in priors]
        return np.concatenate([mp - yp, mq - yq, extra])

    th0 = np.array([0.0, m_to_mm(est.v_ball_before_mps), p.coef[0], m_to_mm(est.v_ball_after_mps), q.coef[0]])
    res = least_squares(resid, th0, method="lm", x_scale=np.array([1e-4, 100.0, 1e3, 100.0, 1e3]),
                        xtol=1e-14, ftol=1e-14, gtol=1e-14)
    th = res.x
    r = res.fun[: tp.size + tq.size]
    n = r.size
    s2 = float(r @ r) / max(n - 5 + len(priors), 1)
    try:
        cov_th = s2 * np.linalg.inv(res.jac.T @ res.jac)
    except np.linalg.LinAlgError:
        cov_th = np.full((5, 5), np.nan)
    t_i = t0 + th[0]
    vm, vp = mm_to_m(th[1]), mm_to_m(th[3])
    vs = float(s_fit.velocity_mps(t_i))
    e = -(vp - vs) / (vm - vs)
    # gradient of e over theta (t_i enters through v_s only; v-, v+ are the values at t_i)
    dvs_dt = float(s_fit.acceleration_mps2(t_i))
    de_dvs = (vm - vp) / (vm - vs) ** 2
    g_th = np.zeros(5)
    g_th[0] = de_dvs * dvs_dt
    dv_dth = mm_to_m(1.0)  # theta's velocities are in mm/s: v (m/s) = mm_to_m(theta)
    g_th[1] = dv_dth * (vp - vs) / (vm - vs) ** 2
    g_th[3] = -dv_dth / (vm - vs)
    var = float(g_th @ cov_th @ g_th)
    # structure contribution (theta held fixed)
    if s_fit.cov_ref is not None:
        sp0 = np.asarray(s_fit.params_ref, float)
        sd = np.sqrt(np.clip(np.diag(s_fit.cov_ref), 0, None))

        def cor_of(sp):
            vs2 = float(with_params(s_fit, sp).velocity_mps(t_i))
            return (-(vp - vs2) / (vm - vs2),)

        jac = central_jacobian(cor_of, sp0, sd)
        gs = jac[0] if jac.shape[0] else np.zeros(sp0.size)
        var += float(gs @ s_fit.cov_ref @ gs)
    return ImpactFit(index=est.index, t_s=float(t_i), t_std_s=float(np.sqrt(max(cov_th[0, 0], 0))), plate=est.plate,
                     cor=float(e), cor_std=float(np.sqrt(max(var, 0))), v_ball_before_mps=float(vm),
                     v_ball_after_mps=float(vp), v_structure_mps=vs, y_rel_mm=float(y_plate_mm),
                     flight_before=est.flight_before, flight_after=est.flight_after, method="joint", structure=s_fit,
                     in_gap=est.in_gap, gap_lost_frames=est.gap_lost_frames)


def finite_difference_cor(t_s: np.ndarray, ball_mm: np.ndarray, structure_mm: np.ndarray,
                          t_impact_s: float) -> float | None:
    """Baseline COR from central differences of the track around an impact at ``t_impact_s``.

    With k the last frame before and k+1 the first after the impact: v- is the central difference at
    frame k-1 (frames k-2, k), v+ at frame k+2 (frames k+1, k+3), for ball and structure alike.
    Returns None when one of those frames is missing (NaN) or out of range.
    """
    k = int(np.searchsorted(t_s, t_impact_s)) - 1
    if k - 2 < 0 or k + 3 >= t_s.size:
        return None

    def cd(y, i):
        return mm_to_m(y[i + 1] - y[i - 1]) / (t_s[i + 1] - t_s[i - 1])

    vm, vsm = cd(ball_mm, k - 1), cd(structure_mm, k - 1)
    vp, vsp = cd(ball_mm, k + 2), cd(structure_mm, k + 2)
    e = -(vp - vsp) / (vm - vsm)
    return float(e) if np.isfinite(e) else None
