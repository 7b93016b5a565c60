"""One-step-ahead predictions: each flight and its closing impact predicted from the measured state
after the previous impact, so errors do not compound (SI units, DIC frame).

The measured state of flight k (position and velocity just after its opening impact) is the one the
judged model estimates from the flight's own frames (its per-flight y0, v0). From it the model
predicts (1) the flight's shape (residual RMS over its frames), (2) the closing impact: the time
the ball reaches the plate level measured for that plate, the velocity before it, the COR from the
model's law and so the velocity after, which is compared with the measured state of the next flight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vibro_discrepancy.data import Measured, speed_mps
from vibro_discrepancy.model import FittedModel, model_plate_levels
from vibro_model.units import m_to_mm, s_to_ms

STEP_S = 2e-5
EXTRA_S = 0.012     # look for the closing impact up to this long after the measured one


@dataclass(kw_only=True)
class OneStep:
    """Per-flight and per-impact one-step errors of one model (arrays; NaN where not predictable)."""

    flight_t_s: np.ndarray          # flight mid time
    flight_direction: np.ndarray    # "up"/"down" (towards the top/bottom plate)
    flight_rms_m: np.ndarray        # shape residual RMS
    flight_sigma_m: float           # noise floor (per frame)
    impact_index: np.ndarray        # into Measured.impacts
    impact_t_s: np.ndarray
    impact_plate: np.ndarray
    impact_speed_mps: np.ndarray     # measured |relative speed| before
    impact_dt_s: np.ndarray         # predicted - measured impact time
    impact_dv_mps: np.ndarray        # predicted - measured ball velocity after the impact
    impact_de: np.ndarray           # measured - predicted COR at the measured impact
    dv_sigma_mps: np.ndarray         # noise floor of the measured velocity after each impact

    def summary(self) -> dict:
        """RMS errors (mm, ms, m/s, COR) over the predictable flights/impacts."""
        def rms(x):
            x = x[np.isfinite(x)]
            return float(np.sqrt(np.mean(x ** 2))) if x.size else None
        out = {"flight_rms_mm": rms(self.flight_rms_m), "impact_time_rms_ms": rms(self.impact_dt_s),
               "impact_velocity_rms_mps": rms(self.impact_dv_mps), "impact_cor_rms": rms(self.impact_de),
               "n_flights": int(np.isfinite(self.flight_rms_m).sum()),
               "n_impacts": int(np.isfinite(self.impact_dv_mps).sum())}
        out["flight_rms_mm"] = m_to_mm(out["flight_rms_mm"])
        out["impact_time_rms_ms"] = s_to_ms(out["impact_time_rms_ms"])
        return out


def _integrate(model: FittedModel, mass_kg: float, y0: np.ndarray, v0: np.ndarray, n_steps: int,
               t_ref_s: np.ndarray | None = None):
    """RK4 of y'' = a(v) for all flights at once (a(t, y, v), :meth:`FittedModel.flight_accel`, for a model
    whose force depends on the ball's position; ``t_ref_s`` the flights' start times); returns (y, v) of shape
    (n_steps + 1, n_flights)."""
    h = STEP_S
    ys = np.empty((n_steps + 1, y0.size))
    vs = np.empty_like(ys)
    y, v = y0.copy(), v0.copy()
    ys[0], vs[0] = y, v
    if model.state_dependent:
        t0 = np.zeros_like(y0) if t_ref_s is None else np.asarray(t_ref_s, dtype=float)
        a = lambda t, yy, vv: model.flight_accel(t, yy, vv, mass_kg)  # noqa: E731
        for i in range(n_steps):
            t = t0 + i * h
            k1y, k1v = v, a(t, y, v)
            k2y, k2v = v + 0.5 * h * k1v, a(t + 0.5 * h, y + 0.5 * h * k1y, v + 0.5 * h * k1v)
            k3y, k3v = v + 0.5 * h * k2v, a(t + 0.5 * h, y + 0.5 * h * k2y, v + 0.5 * h * k2v)
            k4y, k4v = v + h * k3v, a(t + h, y + h * k3y, v + h * k3v)
            y = y + h / 6.0 * (k1y + 2 * k2y + 2 * k3y + k4y)
            v = v + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
            ys[i + 1], vs[i + 1] = y, v
        return ys, vs
    acc = lambda vv: model.accel(vv, mass_kg)  # noqa: E731
    for i in range(n_steps):
        k1v = acc(v)
        k2v = acc(v + 0.5 * h * k1v)
        k3v = acc(v + 0.5 * h * k2v)
        k4v = acc(v + h * k3v)
        y = y + h * (v + h / 6.0 * (k1v + k2v + k3v))
        v = v + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
        ys[i + 1], vs[i + 1] = y, v
    return ys, vs


def _velocity_sigmas(meas: Measured, sigma_m: float) -> np.ndarray:
    """Per flight, the std (m/s) of its measured initial velocity v0: sigma^2 (L^T L)^-1 of its [1, tau] fit,
    ``sigma_m`` the ball's per-frame noise floor (m)."""
    v_sigma = np.empty(len(meas.flights))
    for k, fl in enumerate(meas.flights):
        L = np.column_stack([np.ones_like(fl.tau_s), fl.tau_s])
        v_sigma[k] = sigma_m * np.sqrt(np.linalg.inv(L.T @ L)[1, 1])
    return v_sigma


@dataclass(frozen=True)
class _ClosingFlights:
    """The flights that an impact closes, integrated from their measured states: ``pairs`` (flight, closing
    impact), ``ys``/``vs`` position (m) and velocity (m/s) per step (rows) and flight (columns), ``tau_s``
    the steps' times after each flight's reference time (s)."""

    pairs: list[tuple[int, int]]
    ys: np.ndarray
    vs: np.ndarray
    tau_s: np.ndarray


def _integrate_closing(meas: Measured, model: FittedModel) -> _ClosingFlights | None:
    """Every flight with a closing impact integrated under ``model`` (:func:`_integrate`) until ``EXTRA_S``
    after the longest of them ends; None without such a flight."""
    flights = meas.flights
    pairs = [(k, fl.close_impact) for k, fl in enumerate(flights) if fl.close_impact is not None]
    if not pairs:
        return None
    ks = np.array([k for k, _ in pairs])
    durations = np.array([flights[k].t_end_s - flights[k].t_ref_s for k in ks])
    n_steps = int(np.ceil((durations.max() + EXTRA_S) / STEP_S))
    ys, vs = _integrate(model, meas.mass_kg, model.flights.y0[ks], model.flights.v0[ks], n_steps,
                        np.array([flights[k].t_ref_s for k in ks]))
    return _ClosingFlights(pairs, ys, vs, np.arange(n_steps + 1) * STEP_S)


def _predicted_impact(meas: Measured, model: FittedModel, closing: _ClosingFlights, j: int, level: float
                      ) -> tuple[float, float] | None:
    """The ``j``-th closing flight's predicted closing impact: (time s, ball velocity after it m/s) where its
    integrated run first reaches the plate's ``level`` (ball - structure, m) after its first frames; None when
    it never does."""
    k, ii = closing.pairs[j]
    ys, vs, tau_s = closing.ys[:, j], closing.vs[:, j], closing.tau_s
    imp, fl, S = meas.impacts[ii], meas.flights[k], model.motion
    t_abs = fl.t_ref_s + tau_s
    rel = ys - S.position(t_abs)
    gap = (level - rel) if imp.plate == "top" else (rel - level)
    # first crossing after the flight's last frame's neighbourhood (the ball leaves the plate first)
    start = int(np.searchsorted(tau_s, 0.5 * (fl.t_s[0] - fl.t_ref_s) + 1e-4))
    idx = np.flatnonzero(gap[start:] <= 0.0)
    if idx.size == 0:
        return None
    m = start + int(idx[0])
    if m == 0:
        return None
    g0, g1 = gap[m - 1], gap[m]
    frac = g0 / (g0 - g1) if g0 != g1 else 0.0
    t_pred = t_abs[m - 1] + frac * STEP_S
    vb = vs[m - 1] + frac * (vs[m] - vs[m - 1])
    vsx = float(S.velocity(t_pred))
    e = float(model.cor_at(np.array([imp.plate]), np.array([abs(vb - vsx)]), np.array([ii]))[0])
    return t_pred, vsx - e * (vb - vsx)


def _by_impact(index: np.ndarray, values: np.ndarray) -> dict[int, float]:
    return {int(i): float(x) for i, x in zip(index, values)}


def _impact_errors(meas: Measured, model: FittedModel, v_sigma: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per impact (NaN where not predictable): predicted - measured time (s), predicted - measured velocity
    after (m/s), measured - model COR, and the noise floor of the measured velocity after (m/s; ``v_sigma``
    per flight)."""
    imps = meas.impacts
    levels = model_plate_levels(meas, model)
    dt, dv, de, dv_sig = (np.full(len(imps), np.nan) for _ in range(4))
    closing = _integrate_closing(meas, model)
    if closing is None:
        return dt, dv, de, dv_sig
    # measured impact quantities under this model (for the COR error)
    mi = model.impacts
    e_meas, t_meas = _by_impact(mi.index, mi.cor), _by_impact(mi.index, mi.t_s)
    s_meas, a_meas = _by_impact(mi.index, mi.speed), _by_impact(mi.index, mi.v_after)
    for j, (_, ii) in enumerate(closing.pairs):
        imp = imps[ii]
        level = levels.get(imp.plate)
        if level is None:
            continue
        pred = _predicted_impact(meas, model, closing, j, level)
        if pred is None:
            continue
        t_pred, va_pred = pred
        dt[ii] = t_pred - t_meas.get(ii, imp.t_s)
        if imp.flight_after is not None and ii in a_meas:
            dv[ii] = va_pred - a_meas[ii]
            dv_sig[ii] = v_sigma[imp.flight_after]
        if ii in e_meas:
            e_model = float(model.cor_at(np.array([imp.plate]), np.array([s_meas[ii]]), np.array([ii]))[0])
            de[ii] = e_meas[ii] - e_model
    return dt, dv, de, dv_sig


def one_step(meas: Measured, model: FittedModel, sigma_m: float) -> OneStep:
    """One-step-ahead errors of ``model`` (see the module docstring); ``sigma_m`` is the per-frame
    noise floor of the ball track (m, reported with the errors)."""
    flights, imps = meas.flights, meas.impacts
    dt, dv, de, dv_sig = _impact_errors(meas, model, _velocity_sigmas(meas, sigma_m))
    return OneStep(flight_t_s=np.array([0.5 * (fl.t_s[0] + fl.t_s[-1]) for fl in flights]),
                   flight_direction=np.array([fl.direction for fl in flights], dtype=object),
                   flight_rms_m=model.flights.flight_rms(), flight_sigma_m=float(sigma_m),
                   impact_index=np.arange(len(imps)), impact_t_s=np.array([i.t_s for i in imps]),
                   impact_plate=np.array([i.plate for i in imps], dtype=object),
                   impact_speed_mps=np.array([speed_mps(i) for i in imps]),
                   impact_dt_s=dt, impact_dv_mps=dv, impact_de=de, dv_sigma_mps=dv_sig)
