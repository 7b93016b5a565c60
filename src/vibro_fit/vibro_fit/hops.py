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

from vibro_io.dictrack import DicTrack
from vibro_model.units import mm_to_m

from .contacts import ContactPhase
from .flight_fit import FlightFit
from .impacts import ImpactFit, central_jacobian
from .structure_fit import StructureFit, fit_structure

MIN_HOP_FRAMES = 3
MARGIN_FRAMES = 0.3
SHORT_FLIGHT_POINTS = 6   # a flight opened by a COR impact with fewer than twice this joins the hop chain after it


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


@dataclass(frozen=True, kw_only=True)
class ChainPlate:
    """The plate a chain lands on: ``plate`` ("top"/"bottom"), its level (mm, ball - structure in track
    coordinates) and the structure's local sine fit."""

    plate: str
    level_mm: float
    structure: StructureFit


@dataclass(frozen=True, kw_only=True)
class HopSamples:
    """The track the hops are measured on: frame times ``t`` (s), ball positions ``y`` (mm), ``usable`` (the
    good frames outside contact phases) and ``t_limit`` (s), before which the hops end."""

    t: np.ndarray
    y: np.ndarray
    usable: np.ndarray
    t_limit: float


@dataclass(kw_only=True)
class _Hops:
    """The hops found one after the other: launch times (s; the first is the flight's impact), launch
    velocities (mm/s) and track indices of each hop's frames."""

    starts: list[float]
    velocities: list[float] = field(default_factory=list)
    frames: list[np.ndarray] = field(default_factory=list)


@dataclass(frozen=True, kw_only=True)
class _ChainFit:
    """The joint fit: parameters ``th`` (see :class:`_Chain`), their covariance, the whitened residuals (the
    prior's last), the noise (mm) and its scale-up factor."""

    th: np.ndarray
    cov: np.ndarray
    residuals: np.ndarray
    sigma_mm: float
    scale_noise: float


@dataclass(frozen=True, kw_only=True)
class _ChainImpacts:
    """Impact times (s) and CORs of a fitted chain, the velocities (mm/s: ball in, ball out, structure) at
    each, every impact time with the last hop's landing (None past the limit), and the variances."""

    times: np.ndarray
    cors: np.ndarray
    velocities: list[tuple]
    all_times: list
    var_t: np.ndarray
    var_e: np.ndarray


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


def hop_chain(fl: FlightFit, on: ChainPlate, samples: HopSamples, prior: tuple[float, float], noise_mm: float, *,
              first_impact_index: int, first_flight_index: int) -> HopChain | None:
    """The chain after flight ``fl`` (module rule) landing on the plate ``on``; ``prior``: (median, spread) of
    the acceleration (mm/s^2); ``noise_mm``: the ball's position noise (mm); the chain's impacts and hops are
    numbered from ``first_impact_index`` and ``first_flight_index``. None when not even the first hop holds
    MIN_HOP_FRAMES frames, or the joint fit fails."""
    dt = float(np.median(np.diff(samples.t)))
    chain = _Chain(on.structure, on.level_mm, 1.0 if on.plate == "bottom" else -1.0, dt)
    hops = _find_hops(fl, chain, samples, prior[0])
    if hops is None:
        return None
    fit = _fit_chain(fl, chain, samples, hops, prior, noise_mm)
    if fit is None:
        return None
    imp = _chain_impacts(chain, fit, len(hops.velocities), samples.t_limit + 5 * dt)
    if imp is None:
        return None
    out = HopChain(flight=fl, plate=on.plate, level_mm=on.level_mm)
    for j in range(len(hops.velocities)):
        out.hops.append(_hop_flight(j, on, samples, hops, fit, imp, first_flight_index))
        out.impacts.append(_hop_impact(j, fl, on, imp, first_impact_index, first_flight_index))
    _set_landing(out, fit.th, imp.all_times, on.structure)
    if fit.scale_noise > 1.0:
        out.notes.append(f"residual {fit.scale_noise:.2f} x the noise: sigmas scaled up")
    return out


def _find_hops(fl: FlightFit, chain: _Chain, samples: HopSamples, a0: float) -> _Hops | None:
    """The flight's impact (where its parabola meets the plate) and the hops after it, one after the other
    with the acceleration ``a0`` (mm/s^2), while a hop holds MIN_HOP_FRAMES frames and leaves the plate."""
    t, y = samples.t, samples.y
    t_first = _flight_root(fl, chain, fl.t_end_s, min(fl.t_end_s + 4 * chain.dt, samples.t_limit))
    if t_first is None:
        return None
    margin = MARGIN_FRAMES * chain.dt
    ok = np.asarray(samples.usable, bool) & np.isfinite(y)
    hops = _Hops(starts=[t_first])
    while True:
        t0 = hops.starts[-1]
        cand = np.flatnonzero(ok & (t > t0 + margin) & (t < samples.t_limit))
        if cand.size < MIN_HOP_FRAMES:
            break
        found = _next_hop(chain, t0, a0, cand, samples)
        if found is None:
            break
        use, v, t_land = found
        hops.velocities.append(v)
        hops.frames.append(use)
        hops.starts.append(t_land)
    return hops if hops.velocities else None


def _next_hop(chain: _Chain, t0: float, a0: float, cand: np.ndarray, samples: HopSamples):
    """The hop launched at ``t0`` (s) over the candidate frames ``cand``: (its frames, launch velocity mm/s,
    landing time s), its frames those more than MARGIN_FRAMES before its landing (iterated); None when it
    holds too few frames, does not land before the limit or does not leave the plate."""
    t, y = samples.t, samples.y
    margin = MARGIN_FRAMES * chain.dt
    use = cand[:MIN_HOP_FRAMES]
    t_land = None
    for _ in range(12):
        v = _fit_hop_v(chain, t0, a0, t[use], y[use])
        t_land = chain.landing(t0, v, a0, samples.t_limit)
        hi = t_land - margin if t_land is not None else samples.t_limit
        new = cand[t[cand] < hi]
        if np.array_equal(new, use):
            break
        if new.size < MIN_HOP_FRAMES:
            use = new
            break
        use = new
    if use.size < MIN_HOP_FRAMES or t_land is None:
        return None
    # the hop must leave the plate (relative velocity away from it)
    if chain.sign * (v - float(chain.s.velocity_mps(t0)) * 1e3) <= 0:
        return None
    return use, v, t_land


def _residual_function(fl: FlightFit, chain: _Chain, samples: HopSamples, hops: _Hops,
                       prior: tuple[float, float], sig: float):
    """The whitened residuals of the joint fit as a function of th = [t_1, v_F, A_F, v_1..v_K, A_h]: the
    flight's frames, each hop's frames (noise ``sig``, mm), and the acceleration prior's term last."""
    t, y = samples.t, samples.y
    tf = np.asarray(fl.frames, int)
    k = len(hops.velocities)
    mu, tau = prior
    s_fit, level = chain.s, chain.L

    def resid(th):
        t1, vf, af = th[0], th[1], th[2]
        d = t[tf] - t1
        yf = s_fit.position_mm(t1) + level + vf * d + af * d * d
        out = [(yf - y[tf]) / sig]
        ts = chain.times(th, k - 1, samples.t_limit + 5 * chain.dt)
        for j in range(k):
            t0 = ts[j] if ts[j] is not None else hops.starts[j]
            tau_ = t[hops.frames[j]] - t0
            yh = s_fit.position_mm(t0) + level + th[3 + j] * tau_ + th[-1] * tau_ * tau_
            out.append((yh - y[hops.frames[j]]) / sig)
        out.append(np.array([(th[-1] - mu) / tau]))
        return np.concatenate(out)

    return resid


def _fit_chain(fl: FlightFit, chain: _Chain, samples: HopSamples, hops: _Hops, prior: tuple[float, float],
               noise_mm: float) -> _ChainFit | None:
    """Everything fitted together by least squares (module docstring), with the covariance from the whitened
    Jacobian, the noise scaled up when the residual exceeds it; None when the fit fails."""
    k = len(hops.velocities)
    t_first = hops.starts[0]
    v_f0 = 2.0 * fl.coef[0] * (t_first - fl.t_ref_s) + fl.coef[1]
    th0 = np.array([t_first, v_f0, fl.coef[0], *hops.velocities, prior[0]])
    sig = max(float(noise_mm), 1e-7)
    resid = _residual_function(fl, chain, samples, hops, prior, sig)
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
    return _ChainFit(th=th, cov=cov, residuals=res.fun, sigma_mm=sig, scale_noise=scale_noise)


def _chain_quantities(chain: _Chain, th: np.ndarray, k: int, t_max: float):
    """Impact times (s), CORs, velocities (mm/s: in, out, structure) and all impact times of the chain with
    parameters ``th`` and ``k`` hops; None when an impact falls past ``t_max``."""
    ts = chain.times(th, k, t_max)
    out_t, out_e, out_v = [], [], []
    for j in range(k):
        ti = ts[j]
        if ti is None:
            return None
        if j == 0:
            vin = th[1]
        else:
            vin = th[3 + j - 1] + 2.0 * th[-1] * (ti - ts[j - 1])
        vout = th[3 + j]
        vsi = float(chain.s.velocity_mps(ti)) * 1e3
        out_t.append(ti)
        out_e.append(-(vout - vsi) / (vin - vsi))
        out_v.append((vin, vout, vsi))
    return np.array(out_t), np.array(out_e), out_v, ts


def _chain_impacts(chain: _Chain, fit: _ChainFit, k: int, t_max: float) -> _ChainImpacts | None:
    """The fitted chain's impacts with the variances of their times and CORs (first-order propagation of the
    fit's covariance); None when an impact falls past ``t_max`` (s)."""
    base = _chain_quantities(chain, fit.th, k, t_max)
    if base is None:
        return None
    t_imp, e_imp, v_imp, ts_all = base
    sd = np.sqrt(np.clip(np.diag(fit.cov), 0, None))

    def times_and_cors(x):
        q = _chain_quantities(chain, x, k, t_max)
        return None if q is None else np.concatenate([q[0], q[1]])

    jac = central_jacobian(times_and_cors, fit.th, sd)
    if jac.shape[0] == 0:
        jac = np.zeros((2 * k, fit.th.size))
    jac_t, jac_e = jac[:k], jac[k:]
    var_t = np.einsum("ij,jk,ik->i", jac_t, fit.cov, jac_t)
    var_e = np.einsum("ij,jk,ik->i", jac_e, fit.cov, jac_e)
    return _ChainImpacts(times=t_imp, cors=e_imp, velocities=v_imp, all_times=ts_all, var_t=var_t, var_e=var_e)


def _hop_flight(j: int, on: ChainPlate, samples: HopSamples, hops: _Hops, fit: _ChainFit, imp: _ChainImpacts,
                first_flight_index: int) -> FlightFit:
    """Hop ``j`` as a flight: a parabola about its mid time (FlightFit's convention), not free."""
    t, frames, th = samples.t, hops.frames[j], fit.th
    t_end = imp.all_times[j + 1] if imp.all_times[j + 1] is not None else float(t[frames[-1]])
    a_ = float(th[-1])
    t0 = float(imp.times[j])
    t_ref = 0.5 * (t0 + t_end)
    d = t_ref - t0
    c = float(on.structure.position_mm(t0)) + on.level_mm + th[3 + j] * d + a_ * d * d
    b = th[3 + j] + 2.0 * a_ * d
    hop = FlightFit(index=first_flight_index + j, frames=np.asarray(frames, int), t_start_s=float(t[frames[0]]),
                    t_end_s=float(t[frames[-1]]), t_ref_s=t_ref, coef=np.array([a_, b, c]),
                    cov=np.full((3, 3), np.nan),
                    rms_residual_mm=float(np.sqrt(np.mean((fit.residuals[:-1]) ** 2)) * fit.sigma_mm),
                    n_points=int(len(frames)), fitted=True,
                    is_free=False, reason="short hop: launched from the plate's level, acceleration from the "
                    "free flights (hop chain); no friction from it",
                    direction="up" if on.plate == "bottom" else "down")
    hop.notes.append(f"hop between impacts at {t0:.5f} and {t_end:.5f} s")
    return hop


def _hop_impact(j: int, fl: FlightFit, on: ChainPlate, imp: _ChainImpacts, first_impact_index: int,
                first_flight_index: int) -> ImpactFit:
    """The chain's impact ``j`` (the landing of flight ``fl`` for j = 0, else of hop j - 1) with its sigmas."""
    vin, vout, vsi = imp.velocities[j]
    return ImpactFit(
        index=first_impact_index + j, t_s=float(imp.times[j]), t_std_s=float(np.sqrt(max(imp.var_t[j], 0.0))),
        plate=on.plate, cor=float(imp.cors[j]), cor_std=float(np.sqrt(max(imp.var_e[j], 0.0))),
        v_ball_before_mps=mm_to_m(vin), v_ball_after_mps=mm_to_m(vout), v_structure_mps=mm_to_m(vsi),
        y_rel_mm=on.level_mm, flight_before=fl.index if j == 0 else first_flight_index + j - 1,
        flight_after=first_flight_index + j, method="hop_chain", structure=on.structure)


def _set_landing(out: HopChain, th: np.ndarray, ts_all: list, s_fit: StructureFit) -> None:
    """Where the last hop lands (s), its duration (s) and the relative speed there (m/s), when before the limit."""
    k = len(ts_all) - 1
    if ts_all[k] is None:
        return
    out.landing_s = float(ts_all[k])
    out.last_hop_s = float(ts_all[k] - ts_all[k - 1])
    v_land = th[3 + k - 1] + 2.0 * th[-1] * (ts_all[k] - ts_all[k - 1])
    out.landing_v_rel_mps = mm_to_m(v_land) - float(s_fit.velocity_mps(ts_all[k]))


# ------------------------------------------------------------------ where the chains start
@dataclass(frozen=True, kw_only=True)
class _ChainSearch:
    """What every chain of a recording is measured with: the track, its usable frames, the excitation
    frequency (Hz), the plates' levels (mm), the acceleration prior, the noise (mm), the COR impacts and the
    flights by index."""

    track: DicTrack
    usable: np.ndarray
    f_hz: float
    levels: dict
    prior: tuple[float, float]
    noise_mm: float
    impacts: list[ImpactFit]
    by_index: dict


def chains_after_open_flights(flights: list[FlightFit], impacts: list[ImpactFit], levels: dict, *,
                              contacts: list[ContactPhase], cframes: set[int], track: DicTrack, f_hz: float,
                              noise_mm: float) -> list[HopChain]:
    """The short hops after every free flight that no COR impact closes: the plate's level from the impacts'
    ``levels``, else from its contact phases; hops stop before a contact phase or the next fitted flight;
    ``cframes``: the contact phases' frames (never a hop's); ``f_hz``: the excitation's frequency (Hz)."""
    prior = acceleration_prior(flights)
    if prior is None:
        return []
    t = track.t_s
    usable = track.good.copy()
    if cframes:
        usable[np.fromiter(cframes, int)] = False
    search = _ChainSearch(track=track, usable=usable, f_hz=f_hz, levels=_chain_levels(levels, contacts),
                          prior=prior, noise_mm=noise_mm, impacts=impacts, by_index={f.index: f for f in flights})
    dt = float(np.median(np.diff(t)))
    closed = {i.flight_before for i in impacts}
    fitted = sorted([f for f in flights if f.fitted], key=lambda f: f.t_start_s)
    chains: list[HopChain] = []
    n_imp, n_fl = 10 ** 6, 10 ** 6   # temporary indices, renumbered when merged with the flights
    for k, fl in enumerate(fitted):
        if not fl.is_free or fl.index in closed:
            continue
        t_lim = float(t[-1]) + dt
        if k + 1 < len(fitted):
            t_lim = min(t_lim, fitted[k + 1].t_start_s)
        later = [c.start_s for c in contacts if c.start_s > fl.t_end_s]
        if later:
            t_lim = min(t_lim, later[0])
        ch = _chain_from(fl, search, t_lim, (n_imp, n_fl))
        if ch is not None:
            chains.append(ch)
            n_imp += len(ch.impacts)
            n_fl += len(ch.hops)
    return chains


def _chain_levels(levels: dict, contacts: list[ContactPhase]) -> dict[str, float]:
    """Each plate's level (mm): the COR impacts', else the median of its contact phases' levels."""
    lv = {p: levels[p] for p in ("top", "bottom") if p in levels}
    for plate in ("top", "bottom"):
        vals = [c.level_mm for c in contacts if c.plate == plate]
        if plate not in lv and vals:
            lv[plate] = float(np.median(vals))
    return lv


def _structure_near(search: _ChainSearch, t_from: float, t_lim: float, min_frames: int = 0) -> StructureFit | None:
    """The structure's sine fitted on the good frames from one period before ``t_from`` to ``t_lim`` (s); None
    with fewer than ``min_frames`` of them."""
    t, good = search.track.t_s, search.track.good
    w = (t >= t_from - 1.0 / search.f_hz) & (t <= t_lim) & good
    if w.sum() < min_frames:
        return None
    return fit_structure(t[w], search.track.structure_mm[w], f0_hz=search.f_hz)


def _chain_from(fl: FlightFit, search: _ChainSearch, t_lim: float, first: tuple[int, int]) -> HopChain | None:
    """The chain after flight ``fl`` ending before ``t_lim`` (s), numbered from ``first`` (impact, flight): a
    short flight opened by a COR impact on the same plate is the chain's first hop, the chain then starting
    from the flight before it (its launch sits on the plate's level, its sigma is the chain's)."""
    s_fit = _structure_near(search, fl.t_start_s, t_lim, min_frames=8)
    if s_fit is None:
        return None
    v_end = float(fl.velocity_mps(fl.t_end_s) - s_fit.velocity_mps(fl.t_end_s))
    plate = "bottom" if v_end < 0 else "top"
    if plate not in search.levels:
        return None
    start, replaced = fl, None
    opened = next((i for i in search.impacts if i.flight_after == fl.index), None)
    prev = search.by_index.get(opened.flight_before) if opened is not None else None
    if opened is not None and opened.plate == plate and fl.n_points < 2 * SHORT_FLIGHT_POINTS \
            and prev is not None and prev.is_free:
        start, replaced = prev, (opened, fl)
        s_fit = _structure_near(search, prev.t_start_s, t_lim)
    on = ChainPlate(plate=plate, level_mm=search.levels[plate], structure=s_fit)
    samples = HopSamples(t=search.track.t_s, y=search.track.ball_mm, usable=search.usable, t_limit=t_lim)
    kw = dict(first_impact_index=first[0], first_flight_index=first[1])
    ch = hop_chain(start, on, samples, search.prior, search.noise_mm, **kw)
    if ch is None and replaced is not None:
        ch = hop_chain(fl, on, samples, search.prior, search.noise_mm, **kw)
        replaced = None
    if ch is not None:
        ch.replaces = replaced
    return ch
