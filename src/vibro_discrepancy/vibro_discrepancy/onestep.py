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


@dataclass
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


def one_step(meas: Measured, model: FittedModel, sigma_m: float) -> OneStep:
    """One-step-ahead errors of ``model`` (see the module docstring); ``sigma_m`` is the per-frame
    noise floor of the ball track (reported with the errors)."""
    flights = meas.flights
    nf = len(flights)
    fm = model.flights
    levels = model_plate_levels(meas, model)
    S = model.motion
    flight_t = np.array([0.5 * (fl.t_s[0] + fl.t_s[-1]) for fl in flights])
    flight_dir = np.array([fl.direction for fl in flights], dtype=object)
    flight_rms = fm.flight_rms()
    # state noise: sigma^2 (L^T L)^-1 of each flight's [1, tau] fit -> std of v0
    v_sigma = np.empty(nf)
    for k, fl in enumerate(flights):
        L = np.column_stack([np.ones_like(fl.tau_s), fl.tau_s])
        v_sigma[k] = sigma_m * np.sqrt(np.linalg.inv(L.T @ L)[1, 1])

    imps = meas.impacts
    n_i = len(imps)
    dt = np.full(n_i, np.nan)
    dv = np.full(n_i, np.nan)
    de = np.full(n_i, np.nan)
    dv_sig = np.full(n_i, np.nan)
    speeds = np.array([speed_mps(i) for i in imps])
    closing = [(k, fl.close_impact) for k, fl in enumerate(flights) if fl.close_impact is not None]
    if closing:
        ks = np.array([k for k, _ in closing])
        durations = np.array([flights[k].t_end_s - flights[k].t_ref_s for k in ks])
        n_steps = int(np.ceil((durations.max() + EXTRA_S) / STEP_S))
        ys, vs = _integrate(model, meas.mass_kg, fm.y0[ks], fm.v0[ks], n_steps,
                            np.array([flights[k].t_ref_s for k in ks]))
        tau = np.arange(n_steps + 1) * STEP_S
        # measured impact quantities under this model (for the COR error)
        e_meas = {int(i): float(e) for i, e in zip(model.impacts.index, model.impacts.cor)}
        t_meas = {int(i): float(t) for i, t in zip(model.impacts.index, model.impacts.t_s)}
        s_meas = {int(i): float(x) for i, x in zip(model.impacts.index, model.impacts.speed)}
        a_meas = {int(i): float(x) for i, x in zip(model.impacts.index, model.impacts.v_after)}
        for j, (k, ii) in enumerate(closing):
            imp = imps[ii]
            fl = flights[k]
            t_abs = fl.t_ref_s + tau
            level = levels.get(imp.plate)
            if level is None:
                continue
            rel = ys[:, j] - S.position(t_abs)
            gap = (level - rel) if imp.plate == "top" else (rel - level)
            # first crossing after the flight's last frame's neighbourhood (the ball leaves the plate first)
            start = int(np.searchsorted(tau, 0.5 * (fl.t_s[0] - fl.t_ref_s) + 1e-4))
            idx = np.flatnonzero(gap[start:] <= 0.0)
            if idx.size == 0:
                continue
            m = start + int(idx[0])
            if m == 0:
                continue
            g0, g1 = gap[m - 1], gap[m]
            frac = g0 / (g0 - g1) if g0 != g1 else 0.0
            t_pred = t_abs[m - 1] + frac * STEP_S
            vb = vs[m - 1, j] + frac * (vs[m, j] - vs[m - 1, j])
            vsx = float(S.velocity(t_pred))
            e = float(model.cor_at(np.array([imp.plate]), np.array([abs(vb - vsx)]), np.array([ii]))[0])
            va_pred = vsx - e * (vb - vsx)
            dt[ii] = t_pred - t_meas.get(ii, imp.t_s)
            if imp.flight_after is not None and ii in a_meas:
                dv[ii] = va_pred - a_meas[ii]
                dv_sig[ii] = v_sigma[imp.flight_after]
            if ii in e_meas:
                e_model = float(model.cor_at(np.array([imp.plate]), np.array([s_meas[ii]]), np.array([ii]))[0])
                de[ii] = e_meas[ii] - e_model
    return OneStep(flight_t, flight_dir, flight_rms, float(sigma_m), np.arange(n_i),
                   np.array([i.t_s for i in imps]), np.array([i.plate for i in imps], dtype=object), speeds,
                   dt, dv, de, dv_sig)
