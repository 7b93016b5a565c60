"""The two deviations of a fitted model on the paper's Eq. 18 scale (see :mod:`.engine`): the paper's
free-running D (:func:`full_run`) and the restarted D_r (:func:`restarted_run`). SI, DIC frame."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from vibro_discrepancy.data import Measured
from vibro_discrepancy.model import FittedModel, model_plate_levels, moved_plates
from vibro_sim.cor_model import simulate_cor
from vibro_sim.deviation import Restart, deviation, restarted_deviation

log = logging.getLogger(__name__)


@dataclass
class FullRun:
    """A model simulated over (part of) the recording: times (s), simulated and measured ball (m, DIC frame),
    D (Eq. 18) or None with the error that stopped it."""

    t_s: np.ndarray
    simulated_m: np.ndarray | None
    measured_m: np.ndarray
    deviation: float | None
    error: str | None = None


def full_run(meas: Measured, model: FittedModel) -> FullRun:
    """Simulate ``model`` over the recording from the measured state after the first impact that opens a
    fitted flight; D against the measured ball (DIC frame)."""
    t_all, y_all = meas.t_s, meas.ball_m
    k0 = next((k for k, fl in enumerate(meas.flights) if fl.open_impact is not None), None)
    if k0 is None:
        return FullRun(t_all, None, y_all, None, "no flight opened by an impact")
    fl = meas.flights[k0]
    t_imp = dict(zip((int(i) for i in model.impacts.index), (float(t) for t in model.impacts.t_s)))
    t0 = t_imp.get(int(fl.open_impact), fl.t_ref_s)
    y_start, v_start = (float(x) for x in model.flights.state(k0, t0 - fl.t_ref_s))
    keep = t_all >= t0
    t, y = t_all[keep], y_all[keep]
    if t.size < 2:
        return FullRun(t, None, y, None, "too few frames after the first impact")
    try:
        lv = model_plate_levels(meas, model)
        c0, b = lv["offset"], lv["free_play"]
        S = model.motion
        plates = moved_plates(meas, model)
        top, bottom = (float(plates.get(p, S).position(t0) - S.position(t0)) for p in ("top", "bottom"))
        rel = y_start + c0 - float(S.position(t0))
        rel = min(max(rel, bottom - b * (1 - 1e-9)), top + b * (1 - 1e-9))
        res = simulate_cor(S, model.cavity(meas, b), model.restitution_law(), model.force_law(),
                           y0_m=float(S.position(t0)) + rel, v0_mps=v_start, t0_s=t0, t_end_s=float(t[-1]),
                           plates=plates)
        sim = np.asarray(res.sample(t), dtype=float) - c0
        return FullRun(t, sim, y, float(deviation(t, sim, y)))
    except Exception as exc:  # a model that cannot be simulated must not lose the analysis
        log.warning("discrepancy full run of %s failed: %s", model.label(), exc)
        return FullRun(t, None, y, None, f"{type(exc).__name__}: {exc}")


def restart_points(meas: Measured, model: FittedModel) -> list[Restart]:
    """The measured state after each impact that opens a fitted flight, as ``model`` measures it (the
    paper's Eq. 14 with the model's flight law in place of Eq. 3): the flight's fitted position and
    velocity (DIC frame, m and m/s) at the impact time where the model's flights meet (Eq. 15 under the
    model; the identified time if the model has none for it). The window ends at the impact that closes
    the flight, else at its last fitted frame.

    Not the identified parabola (Eq. 3) at the identified time: under a speed-dependent force the
    parabola's start velocity and time are biased (the quadratic-drag case restarted from them keeps
    D_r = 0.0086 with the true law, 170x its noise floor), so the start would judge the parabola, not
    the model."""
    t_imp = dict(zip((int(i) for i in model.impacts.index), (float(t) for t in model.impacts.t_s)))
    out = []
    for k, fl in enumerate(meas.flights):
        if fl.open_impact is None:
            continue
        t0 = t_imp.get(int(fl.open_impact), float(meas.impacts[fl.open_impact].t_s))
        y0, v0 = (float(x) for x in model.flights.state(k, t0 - fl.t_ref_s))
        t1 = fl.t_end_s if fl.close_impact is not None else float(fl.t_s[-1])
        out.append(Restart(t0, t1, y0, v0))
    return out


def restarted_run(meas: Measured, model: FittedModel) -> FullRun:
    """D_r of ``model`` (:func:`vibro_sim.deviation.restarted_deviation`): each fitted flight simulated
    from the measured state after the impact that opens it (:func:`restart_points`), compared with the
    measured ball; the model's plate levels and free play as in :func:`full_run`."""
    try:
        lv = model_plate_levels(meas, model)
        r = restarted_deviation(meas.t_s, meas.ball_m, restart_points(meas, model), model.motion,
                                model.cavity(meas, lv["free_play"]), model.restitution_law(), model.force_law(),
                                frame_offset_m=lv["offset"], plates=moved_plates(meas, model))
        return FullRun(r.t_s, r.simulated_m, r.measured_m, r.deviation)
    except Exception as exc:  # a model that cannot be simulated must not lose the analysis
        log.warning("discrepancy restarted run of %s failed: %s", model.label(), exc)
        return FullRun(meas.t_s[:0], None, meas.ball_m[:0], None, f"{type(exc).__name__}: {exc}")
