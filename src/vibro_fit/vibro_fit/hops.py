"""Short hops: the rebounds too short for a free parabola fit, measured as a chain on the plate.

At a low COR the ball lands and hops on the plate a few times, each hop shorter (8 ms, 4 ms, 2 ms, ...),
before it rides the plate (:mod:`vibro_fit.contacts`). The segmentation leaves a hop of fewer than
``min_points`` unflagged frames unfitted, so the impacts between hops had no COR. Three frames determine a
hop when two things are known from the rest of the recording:

- the plate's level L (ball - structure, track coordinates: the COR impacts' median, or the contact
  phases' level, measured over many frames): every hop starts and ends with the ball on the plate, so the
  impact time is where the hop before it meets the plate, ``Y_b(t_i) = Y_s(t_i) + L``;
- the acceleration in flight: one coefficient A shared by the hops, with a Gaussian prior from the free
  flights (median and spread of their quadratic coefficients, :func:`acceleration_prior`).

Rule (:func:`hop_chains`): a fitted free flight that no COR impact closes and that is followed by short
flights or a contact phase on a plate of known level starts a chain. Its impact is where its parabola
meets the plate; the hop after it is ``Y = Y_s(t_i) + L + v (t - t_i) + A (t - t_i)^2`` fitted on the good
frames between its impact and the next (the root of the same equation), leaving out frames within
``MARGIN_FRAMES`` of a frame interval of either impact (a frame whose exposure may cover the contact).
The next impact is where this hop meets the plate again, and so on while a hop holds at least
``MIN_HOP_FRAMES`` frames; it stops before a contact phase or the next fitted flight. Then everything is
fitted together (the flight's velocity and acceleration at its impact, each hop's launch velocity, A with
its prior; every impact time follows from the hop before it) by least squares on the positions weighted
with the noise; the covariance is the inverse of the whitened normal matrix, with the noise scaled up when
the residual exceeds it. Each impact's COR (Eq. 16) and time get their sigma from it by first-order
propagation. The hops are reported as flights (not free: their acceleration is the prior's, no friction).
Units: mm, s inside (results in m/s).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq, least_squares

from vibro_model.units import mm_to_m

from .flight_fit import FlightFit
from .impacts import ImpactFit, central_jacobian
from .structure_fit import StructureFit

MIN_HOP_FRAMES = 3
MARGIN_FRAMES = 0.3


@dataclass(kw_only=True)
class HopChain:
    """One chain: the flight that lands (``flight``), the hops after it and the impacts between them."""

    flight: FlightFit
    plate: str
    level_mm: float
    impacts: list[ImpactFit] = field(default_factory=list)
    hops: list[FlightFit] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    landing_s: float | None = None       # where the last hop lands (then the unresolved chatter)
    last_hop_s: float | None = None      # the last hop's duration (s)
    replaces: tuple | None = None        # (COR impact, flight) the chain measures again as its first hop
    landing_v_rel_mps: float | None = None   # ball minus plate velocity where the last hop lands


def acceleration_prior(flights: list[FlightFit]) -> tuple[float, float] | None:
    """(median, spread) of the quadratic coefficient A (mm/s^2) of the free flights: the spread is their
    robust std with the fits' own noise taken out, floored at 0.3 x the median fit std and at 0.2 % of
    the median (None with fewer than 2 free flights)."""
    fl = [f for f in flights if f.is_free and f.fitted]
    if len(fl) < 2:
        return None
    a = np.array([f.coef[0] for f in fl])
    var_fit = np.array([f.cov[0, 0] for f in fl])
    med = float(np.median(a))
    robust = 1.4826 * float(np.median(np.abs(a - med)))
    between = robust ** 2 - float(np.median(var_fit))
    floor = max(0.3 * float(np.sqrt(np.median(var_fit))), 0.002 * abs(med))
    return med, max(float(np.sqrt(max(between, 0.0))), floor)


class _Chain:
    """The model of one chain: parameters th = [t_1, v_F, A_F, v_1 .. v_K, A_h] (s, mm/s, mm/s^2)."""

    def __init__(self, s_fit: StructureFit, level: float, sign: float, dt: float):
        self.s = s_fit
        self.L = level
        self.sign = sign          # +1: bottom plate (the ball is above it), -1: top
        self.dt = dt

    def rel(self, t, t0, v, a):
        """The sign times (y_rel - L) at t of a hop launched from the plate at t0 with v (mm/s), a (mm/s^2)."""
        tau = np.asarray(t) - t0
        y = self.s.position_mm(t0) + self.L + v * tau + a * tau * tau
        return self.sign * (y - self.s.position_mm(np.asarray(t)) - self.L)

    def landing(self, t0, v, a, t_max):
        """The first time after t0 where the hop is back on the plate (None before t_max)."""
        lo = t0 + 1e-3 * self.dt
        if t_max <= lo:
            return None
        return first_crossing(lambda t: self.rel(t, t0, v, a), lo, t_max, 0.05 * self.dt)

    def times(self, th, k_hops, t_max):
        """Impact times t_1 .. t_{K+1} (the last: where the last hop lands, None past t_max)."""
        ts = [th[0]]
        a = th[-1]
        for k in range(k_hops):
            nxt = self.landing(ts[-1], th[3 + k], a, t_max)
            if nxt is None:
                return ts + [None] * (k_hops - k)
            ts.append(nxt)
        return ts


def first_crossing(f, lo: float, hi: float, step: float) -> float | None:
    """The first t in (lo, hi] where ``f`` (vectorised; > 0 at lo: the ball above the plate's level) reaches 0,
    from a grid of about ``step`` (s) and Brent's method in the first interval that crosses; None when ``f`` is not
    positive at ``lo`` or stays positive."""
    grid = np.linspace(lo, hi, max(int((hi - lo) / step) + 2, 3))
    r = np.asarray(f(grid), dtype=float)
    if r[0] <= 0:
        return None
    neg = np.flatnonzero(r <= 0)
    if neg.size == 0:
        return None
    j = int(neg[0])
    return float(brentq(lambda x: float(f(x)), grid[j - 1], grid[j], xtol=1e-14))


def _fit_hop_v(chain: _Chain, t0, a, tt, yy):
    """Launch velocity (mm/s) of a hop from t0 with acceleration a: linear least squares on (tt, yy)."""
    tau = tt - t0
    base = chain.s.position_mm(t0) + chain.L + a * tau * tau
    return float(np.sum((yy - base) * tau) / np.sum(tau * tau))


def _flight_root(fl: FlightFit, chain: _Chain, t_from, t_max):
    """Where a fitted flight's parabola meets the plate after ``t_from`` (None before ``t_max``)."""
    return first_crossing(lambda t: chain.sign * (fl.position_mm(t) - chain.s.position_mm(t) - chain.L),
                          t_from, t_max, 0.05 * chain.dt)


def hop_chain(fl: FlightFit, plate: str, level: float, s_fit: StructureFit, t: np.ndarray, y: np.ndarray,
              usable: np.ndarray, t_limit: float, prior: tuple[float, float], noise_mm: float,
              first_impact_index: int, first_flight_index: int) -> HopChain | None:
    """The chain after flight ``fl`` (module rule) landing on ``plate`` at ``level`` (mm); ``usable``: the
    good frames outside contact phases; hops end before ``t_limit``. None when not even the first hop
    holds MIN_HOP_FRAMES frames."""
    dt = float(np.median(np.diff(t)))
    chain = _Chain(s_fit, level, 1.0 if plate == "bottom" else -1.0, dt)
    margin = MARGIN_FRAMES * dt
    t_first = _flight_root(fl, chain, fl.t_end_s, min(fl.t_end_s + 4 * dt, t_limit))
    if t_first is None:
        return None
    a0 = prior[0]
    ok = np.asarray(usable, bool) & np.isfinite(y)
    starts, vs_, frames = [t_first], [], []
    while True:
        t0 = starts[-1]
        sel = ok & (t > t0 + margin) & (t < t_limit)
        cand = np.flatnonzero(sel)
        if cand.size < MIN_HOP_FRAMES:
            break
        use = cand[:MIN_HOP_FRAMES]
        t_land = None
        for _ in range(12):
            v = _fit_hop_v(chain, t0, a0, t[use], y[use])
            t_land = chain.landing(t0, v, a0, t_limit)
            hi = t_land - margin if t_land is not None else t_limit
            new = cand[t[cand] < hi]
            if np.array_equal(new, use):
                break
            if new.size < MIN_HOP_FRAMES:
                use = new
                break
            use = new
        if use.size < MIN_HOP_FRAMES or t_land is None:
            break
        # the hop must leave the plate (relative velocity away from it)
        if chain.sign * (v - float(s_fit.velocity_mps(t0)) * 1e3) <= 0:
            break
        vs_.append(v)
        frames.append(use)
        starts.append(t_land)
    if not vs_:
        return None
    k = len(vs_)
    # joint fit: th = [t_1, v_F, A_F, v_1..v_K, A_h]
    tf = np.asarray(fl.frames, int)
    v_f0 = 2.0 * fl.coef[0] * (t_first - fl.t_ref_s) + fl.coef[1]
    th0 = np.array([t_first, v_f0, fl.coef[0], *vs_, a0])
    mu, tau = prior
    sig = max(float(noise_mm), 1e-7)

    def resid(th):
        t1, vf, af = th[0], th[1], th[2]
        d = t[tf] - t1
        yf = s_fit.position_mm(t1) + level + vf * d + af * d * d
        out = [(yf - y[tf]) / sig]
        ts = chain.times(th, k - 1, t_limit + 5 * dt)
        for j in range(k):
            t0 = ts[j] if ts[j] is not None else starts[j]
            tau_ = t[frames[j]] - t0
            yh = s_fit.position_mm(t0) + level + th[3 + j] * tau_ + th[-1] * tau_ * tau_
            out.append((yh - y[frames[j]]) / sig)
        out.append(np.array([(th[-1] - mu) / tau]))
        return np.concatenate(out)

    scale = np.array([1e-4, 100.0, 1e3] + [100.0] * k + [1e3])
    try:
        res = least_squares(resid, th0, method="lm", x_scale=scale, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    except (ValueError, RuntimeError):
        return None
    th = res.x
    n_data = res.fun.size - 1
    dof = max(n_data - (th.size - 1), 1)
    chi2 = float(np.sum(res.fun[:-1] ** 2)) / dof
    scale_noise = max(1.0, float(np.sqrt(chi2)))
    try:
        jw = res.jac.copy()
        jw[:-1] /= scale_noise
        cov = np.linalg.inv(jw.T @ jw)
    except np.linalg.LinAlgError:
        return None

    def quantities(th_):
        """Impact times and CORs of the chain, from the parameters."""
        ts = chain.times(th_, k, t_limit + 5 * dt)
        out_t, out_e, out_v = [], [], []
        for j in range(k):
            ti = ts[j]
            if ti is None:
                return None
            if j == 0:
                vin = th_[1]
            else:
                vin = th_[3 + j - 1] + 2.0 * th_[-1] * (ti - ts[j - 1])
            vout = th_[3 + j]
            vsi = float(s_fit.velocity_mps(ti)) * 1e3
            out_t.append(ti)
            out_e.append(-(vout - vsi) / (vin - vsi))
            out_v.append((vin, vout, vsi))
        return np.array(out_t), np.array(out_e), out_v, ts

    base = quantities(th)
    if base is None:
        return None
    t_imp, e_imp, v_imp, ts_all = base
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))

    def times_and_cors(x):
        q = quantities(x)
        return None if q is None else np.concatenate([q[0], q[1]])

    jac = central_jacobian(times_and_cors, th, sd)
    if jac.shape[0] == 0:
        jac = np.zeros((2 * k, th.size))
    jac_t, jac_e = jac[:k], jac[k:]
    var_t = np.einsum("ij,jk,ik->i", jac_t, cov, jac_t)
    var_e = np.einsum("ij,jk,ik->i", jac_e, cov, jac_e)
    out = HopChain(flight=fl, plate=plate, level_mm=level)
    for j in range(k):
        t_end = ts_all[j + 1] if ts_all[j + 1] is not None else float(t[frames[j][-1]])
        a_ = float(th[-1])
        t0 = float(t_imp[j])
        # the hop as a parabola about its mid time (FlightFit's convention)
        t_ref = 0.5 * (t0 + t_end)
        d = t_ref - t0
        c = float(s_fit.position_mm(t0)) + level + th[3 + j] * d + a_ * d * d
        b = th[3 + j] + 2.0 * a_ * d
        hop = FlightFit(index=first_flight_index + j, frames=np.asarray(frames[j], int),
                        t_start_s=float(t[frames[j][0]]),
                        t_end_s=float(t[frames[j][-1]]), t_ref_s=t_ref, coef=np.array([a_, b, c]), cov=np.full((3, 3),
                                                                                                               np.nan),
                        rms_residual_mm=float(np.sqrt(np.mean((res.fun[:-1]) ** 2)) * sig),
                        n_points=int(len(frames[j])), fitted=True,
                        is_free=False, reason="short hop: launched from the plate's level, acceleration from the "
                        "free flights (hop chain); no friction from it",
                        direction="up" if plate == "bottom" else "down")
        hop.notes.append(f"hop between impacts at {t0:.5f} and {t_end:.5f} s")
        out.hops.append(hop)
        vin, vout, vsi = v_imp[j]
        out.impacts.append(ImpactFit(
            index=first_impact_index + j, t_s=t0, t_std_s=float(np.sqrt(max(var_t[j], 0.0))), plate=plate,
            cor=float(e_imp[j]), cor_std=float(np.sqrt(max(var_e[j], 0.0))), v_ball_before_mps=mm_to_m(vin),
            v_ball_after_mps=mm_to_m(vout), v_structure_mps=mm_to_m(vsi), y_rel_mm=level,
            flight_before=fl.index if j == 0 else first_flight_index + j - 1, flight_after=first_flight_index + j,
            method="hop_chain", structure=s_fit))
    if ts_all[k] is not None:
        out.landing_s = float(ts_all[k])
        out.last_hop_s = float(ts_all[k] - ts_all[k - 1])
        v_land = th[3 + k - 1] + 2.0 * th[-1] * (ts_all[k] - ts_all[k - 1])
        out.landing_v_rel_mps = mm_to_m(v_land) - float(s_fit.velocity_mps(ts_all[k]))
    if scale_noise > 1.0:
        out.notes.append(f"residual {scale_noise:.2f} x the noise: sigmas scaled up")
    return out
