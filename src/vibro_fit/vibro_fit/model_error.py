"""The identification's COR sigmas with what its models leave in their residuals (issue 39).

Each impact's COR sigma (:func:`vibro_fit.impacts.paper_impact`) propagates the DIC noise through the two
parabolas and the structure sine. Where a parabola does not describe a flight (a force that depends on the
ball's position, a drag) or the sine not the structure near an impact, the residuals hold a smooth part whose
slope at the impact biases the velocities; :mod:`vibro_model.model_error` estimates it, pooled per plate and
side and counted only where significant, and :func:`model_error_pass` widens every impact's COR sigma by it.
Track units (mm) inside, m/s out. A model that fits keeps its sigmas.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from vibro_io.dictrack import DicTrack
from vibro_io.rig import RigConfig
from vibro_model.model_error import ImpactSlopes, ModelError, flight_residual_slope, local_sine_slope
from vibro_model.units import mm_to_m

from .flight_fit import FlightFit
from .impacts import ImpactFit, paper_impact
from .passes import HopPass

#: fewer free flights: no pooled flight noise (the floor would be as noisy as one flight's own)
MIN_POOLED_FLIGHTS = 5


def _flight_slope(fl: FlightFit | None, track: DicTrack, t_s: float) -> tuple[float, float]:
    """(d, sd) in m/s: the slope at ``t_s`` of the smooth part of flight ``fl``'s parabola residuals."""
    if fl is None or fl.frames is None or len(fl.frames) == 0:
        return math.nan, math.nan
    frames = np.asarray(fl.frames, dtype=int)
    t = np.asarray(track.t_s, dtype=float)[frames]
    r = np.asarray(track.ball_mm, dtype=float)[frames] - np.asarray(fl.position_mm(t), dtype=float)
    d, sd = flight_residual_slope(t - fl.t_ref_s, r, t_s - fl.t_ref_s)
    return mm_to_m(d), mm_to_m(sd)


def _structure_slope(imp: ImpactFit, track: DicTrack, frequency_hz: float) -> tuple[float, float]:
    """(d, sd) in m/s: the slope at the impact of the impact's structure fit's residual within one drive period."""
    s = imp.structure
    if s is None or not math.isfinite(imp.t_s) or not frequency_hz > 0:
        return math.nan, math.nan
    t = np.asarray(track.t_s, dtype=float)
    sel = np.abs(t - imp.t_s) <= 1.0 / frequency_hz
    y = np.asarray(track.structure_mm, dtype=float)[sel]
    r = y - np.asarray(s.position_mm(t[sel]), dtype=float)
    d, sd = local_sine_slope(t[sel] - imp.t_s, r, 2.0 * math.pi * frequency_hz)
    return mm_to_m(d), mm_to_m(sd)


def impact_slopes(impacts: list[ImpactFit], flights: list[FlightFit], track: DicTrack,
                  frequency_hz: float) -> list[ImpactSlopes]:
    """The residual slopes at each impact with a COR (:class:`vibro_model.model_error.ImpactSlopes`)."""
    by_index = {int(f.index): f for f in flights}
    out = []
    for imp in impacts:
        if not math.isfinite(imp.cor):
            continue
        out.append(ImpactSlopes(plate=imp.plate,
                                before=_flight_slope(by_index.get(int(imp.flight_before)), track, imp.t_s),
                                after=_flight_slope(by_index.get(int(imp.flight_after)), track, imp.t_s),
                                structure=_structure_slope(imp, track, frequency_hz)))
    return out


def model_error_pass(impacts: list[ImpactFit], flights: list[FlightFit], track: DicTrack,
                     frequency_hz: float) -> tuple[list[ImpactFit], ModelError]:
    """``impacts`` with each COR sigma widened by the pooled model error of its plate (module docstring), and
    that model error (m/s)."""
    errors = ModelError.of(impact_slopes(impacts, flights, track, frequency_hz))
    out = []
    for imp in impacts:
        var = errors.cor_variance(imp.plate, imp.v_ball_before_mps, imp.v_ball_after_mps, imp.v_structure_mps) \
            if math.isfinite(imp.cor) and math.isfinite(imp.cor_std) else 0.0
        out.append(replace(imp, cor_std=math.sqrt(imp.cor_std ** 2 + var), cor_std_model=math.sqrt(var))
                   if var > 0 else imp)
    return out, errors


def pooled_flight_variance(flights: list[FlightFit]) -> float:
    """The flights' residual variance pooled over the free flights (mm^2): sum of n rms^2 over sum of n - 3
    (a parabola's three coefficients); NaN with fewer than :data:`MIN_POOLED_FLIGHTS`."""
    free = [f for f in flights if f.fitted and f.is_free and f.n_points > 3 and math.isfinite(f.rms_residual_mm)]
    if len(free) < MIN_POOLED_FLIGHTS:
        return math.nan
    sse = sum(f.n_points * f.rms_residual_mm ** 2 for f in free)
    return sse / sum(f.n_points - 3 for f in free)


def _floored(flight: FlightFit, pooled: float) -> FlightFit:
    """``flight`` with its coefficients' covariance scaled up to the pooled residual variance ``pooled`` where its
    own (sigma^2 = n rms^2 / (n - 3)) is lower; the flight unchanged otherwise."""
    own = flight.n_points * flight.rms_residual_mm ** 2 / max(flight.n_points - 3, 1)
    return replace(flight, cov=flight.cov * (pooled / own)) if 0 < own < pooled else flight


def noise_floor_pass(hops: HopPass) -> HopPass:
    """The identification's named pass: each paper impact's sigmas (Eq. 15, 16 propagated) with its two flights'
    covariances at least the recording's pooled flight noise (:func:`pooled_flight_variance`). One flight's
    residual variance rests on 10-40 frames (its sigma scatters by 12-25 %); where it came out lower than the
    camera's noise over every flight, a COR sigma built on it claimed too much (2-sigma coverage 0.88 on a
    rendered control recording). Never lowers a sigma; impacts of other methods and their values unchanged."""
    pooled = pooled_flight_variance(hops.flights)
    if not math.isfinite(pooled) or pooled <= 0:
        return hops
    by_index = {int(f.index): f for f in hops.flights}
    out = []
    for imp in hops.impacts:
        p, q = by_index.get(int(imp.flight_before)), by_index.get(int(imp.flight_after))
        redone = None
        if imp.method == "paper" and p is not None and q is not None and imp.structure is not None:
            fp, fq = _floored(p, pooled), _floored(q, pooled)
            if fp is not p or fq is not q:   # both at or above the floor already: the same propagation again
                redone = paper_impact(imp.index, fp, fq, imp.structure)
        if redone is not None and redone.cor_std > imp.cor_std:
            imp = replace(imp, cor_std=redone.cor_std, t_std_s=max(redone.t_std_s, imp.t_std_s))
        out.append(imp)
    return replace(hops, impacts=out)


def widened_pass(hops: HopPass, track: DicTrack, rig: RigConfig) -> HopPass:
    """The identification's named pass: :func:`model_error_pass` on the hop pass' impacts and flights."""
    impacts, _ = model_error_pass(hops.impacts, hops.flights, track, float(rig.excitation.frequency_hz))
    return replace(hops, impacts=impacts)
